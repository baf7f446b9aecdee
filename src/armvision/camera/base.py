"""The ``Camera`` interface every backend (SimCamera, RealSenseCamera) implements."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from armvision.camera.frames import Intrinsics, RGBDFrame


@runtime_checkable
class Camera(Protocol):
    """An RGB-D camera: colour and depth aligned to the colour stream.

    ``start()`` opens the device (or renderer), ``read(timeout_s)`` returns the newest frame,
    blocking until one newer than the last read exists, and ``stop()`` releases it. Use as a
    context manager: ``with camera: frame = camera.read()``. ``serial``: the device's serial
    number (saved with a calibration), None if it has none.
    """

    @property
    def serial(self) -> str | None: ...

    @property
    def intrinsics(self) -> Intrinsics: ...

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def read(self, timeout_s: float = 1.0) -> RGBDFrame: ...

    def __enter__(self) -> Camera: ...

    def __exit__(self, *exc: object) -> None: ...
