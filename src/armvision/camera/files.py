"""RGB-D frames from saved files: a colour image and a depth image someone already has.

:func:`load_rgbd` turns a colour file and a depth file into the :class:`RGBDFrame` the camera
stage would have produced, so perception runs on a frame from anywhere (a RealSense recording
exported to PNG, a data set, ``armvision sim snapshot``):

- colour: anything OpenCV reads (PNG, JPG, ...), converted from OpenCV's BGR to RGB; grey
  images become three equal channels, an alpha channel is dropped;
- depth, by its file's contents (the extension only picks the reader):

  - 16-bit PNG (or any integer image): raw units times ``depth_scale`` (0.001 for
    millimetres, a RealSense's default; the D400's ``depth_scale`` otherwise);
  - float EXR: metres (``depth_scale`` is not applied to float data);
  - NPY: float (metres) or unsigned 16/32-bit integers (times ``depth_scale``);
  - a depth with several identical channels (EXR depth is often saved as RGB) gives its
    first channel; channels that differ are refused (a false-colour picture is no depth);
  - NaN, infinity, zero and negative values all become 0, "no measurement".

Colour and depth must have the same size (depth aligned to colour, as the camera stage
gives it); intrinsics are ``fx, fy, cx, cy`` at that size, no distortion.

EXR: OpenCV reads its ``OPENCV_IO_ENABLE_OPENEXR`` flag once; this module sets it to 1 (unless
the environment already sets it) when it is imported, before it imports cv2. If cv2 has
already used the EXR codec with the flag off, an EXR file is a :class:`FrameFileError` saying
to start Python with ``OPENCV_IO_ENABLE_OPENEXR=1`` (or to save the depth as NPY).

Every bad input is a :class:`FrameFileError` (a :class:`~armvision.errors.PerceptionError`)
with a one-line message naming the file and what to do.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

#: Whether the environment set OpenCV's EXR flag itself (then it is the user's choice).
_EXR_FLAG = "OPENCV_IO_ENABLE_OPENEXR"
_EXR_FLAG_GIVEN = os.environ.get(_EXR_FLAG)
os.environ.setdefault(_EXR_FLAG, "1")  # before cv2 is imported: OpenCV may read it only once

import cv2  # noqa: E402  (after the flag above)
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from armvision.camera.frames import Intrinsics, RGBDFrame  # noqa: E402
from armvision.errors import PerceptionError  # noqa: E402

#: The depth unit of 16-bit depth when none is given: millimetres (a RealSense's default).
DEFAULT_DEPTH_SCALE = 0.001
#: The largest image file read (a 4K float EXR with three channels is ~100 MB).
_MAX_BYTES = 512 * 1024 * 1024

_INTRINSICS_HELP = (
    "give --intrinsics as fx,fy,cx,cy in pixels at the image's size, e.g. 615,615,319.5,239.5, "
    "or a JSON file with an 'intrinsics' object (a sim snapshot's ground_truth.json)"
)


class FrameFileError(PerceptionError):
    """A saved colour or depth file, or the numbers that go with it, cannot make a frame."""


@contextlib.contextmanager
def _quiet_opencv() -> Iterator[None]:
    """OpenCV's own warnings off (they go to the process's stderr, beside our one line)."""
    logging = getattr(getattr(cv2, "utils", None), "logging", None)
    if logging is None:  # pragma: no cover - every opencv-python build has cv2.utils.logging
        yield
        return
    level = logging.getLogLevel()
    logging.setLogLevel(logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        logging.setLogLevel(level)


def _read_bytes(path: Path, what: str) -> NDArray[np.uint8]:
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise FrameFileError(f"{what} file {path} does not exist: check the path") from None
    except OSError as exc:
        raise FrameFileError(f"{what} file {path}: {exc.strerror or exc}") from None
    if not path.is_file():
        raise FrameFileError(f"{what} file {path} is not a file: give an image file")
    if size == 0:
        raise FrameFileError(f"{what} file {path} is empty: give an image file")
    if size > _MAX_BYTES:
        raise FrameFileError(
            f"{what} file {path} is {size / 1e6:.0f} MB, more than an image of one frame: "
            "check the path"
        )
    try:
        return np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise FrameFileError(f"{what} file {path}: {exc.strerror or exc}") from None


def _exr_disabled(exc: cv2.error) -> bool:
    return "OpenEXR codec is disabled" in str(exc) or "OPENCV_IO_ENABLE_OPENEXR" in str(exc)


def _decode(path: Path, what: str, flags: int) -> NDArray[Any]:
    """An image file through OpenCV (its bytes read here, so any path works)."""
    data = _read_bytes(path, what)
    exr = data[:4].tobytes() == b"\x76\x2f\x31\x01"  # OpenEXR's magic number
    image: NDArray[Any] | None = None
    for attempt in range(2):
        try:
            with _quiet_opencv():
                image = cv2.imdecode(data, flags)
            break
        except cv2.error as exc:
            if not (exr and _exr_disabled(exc)):
                image = None
                break
            if attempt == 0 and _EXR_FLAG_GIVEN is None:
                os.environ[_EXR_FLAG] = "1"  # some OpenCV builds read it on first use
                continue
            given = os.environ.get(_EXR_FLAG)
            raise FrameFileError(
                f"{what} file {path} is EXR, which OpenCV reads only with "
                f"{_EXR_FLAG}=1 set before it starts (it is {given!r} here): run with "
                f"{_EXR_FLAG}=1 in the environment, or save the depth as .npy"
            ) from None
    if image is None:
        raise FrameFileError(
            f"{what} file {path} is not an image OpenCV can read: give a PNG, JPG or EXR"
            + (" (or an .npy array for depth)" if what == "depth" else "")
        )
    return image


def load_color(path: str | os.PathLike[str]) -> NDArray[np.uint8]:
    """(H, W, 3) uint8 RGB of a colour image file; FrameFileError if it is not one."""
    path = Path(path)
    if path.suffix.lower() == ".npy":
        raise FrameFileError(
            f"colour file {path} is an .npy array: give the colour image as PNG or JPG"
        )
    bgr = _decode(path, "colour", cv2.IMREAD_COLOR)
    return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8)


def _one_channel(depth: NDArray[Any], path: Path) -> NDArray[Any]:
    if depth.ndim == 2:
        return depth
    if depth.ndim == 3 and depth.shape[2] >= 1:
        first = depth[:, :, 0]
        rest = depth[:, :, 1:]
        same = np.all((rest == first[:, :, None]) | (np.isnan(rest) & np.isnan(first[:, :, None])))
        if depth.shape[2] == 1 or same:
            return first
        raise FrameFileError(
            f"depth file {path} has {depth.shape[2]} different channels, so it is a picture, "
            "not depth: give the depth itself (16-bit PNG, float EXR or .npy), not a "
            "false-colour image"
        )
    raise FrameFileError(
        f"depth file {path} holds an array of shape {tuple(depth.shape)}: give an (H, W) depth"
    )


def load_depth(
    path: str | os.PathLike[str], depth_scale: float = DEFAULT_DEPTH_SCALE
) -> tuple[NDArray[np.float32], float | None]:
    """(H, W) float32 metres of a depth file, 0 for no data, and the scale applied to it
    (``depth_scale`` for integer depth, None for float depth, metres as it is);
    FrameFileError if it is no depth."""
    path = Path(path)
    check_depth_scale(depth_scale)
    if path.suffix.lower() == ".npy":
        _read_bytes(path, "depth")  # the same messages for a missing or empty file
        try:
            raw = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise FrameFileError(
                f"depth file {path} is not a numpy array file ({reason}): save it with numpy.save"
            ) from None
        if not isinstance(raw, np.ndarray):  # pragma: no cover - np.load of .npy is an array
            raise FrameFileError(f"depth file {path} is not a single array: save one with np.save")
    else:
        raw = _decode(path, "depth", cv2.IMREAD_UNCHANGED)
    depth = _one_channel(np.asarray(raw), path)
    kind = depth.dtype.kind
    if kind == "f":
        metres = depth.astype(np.float64)
        unit: float | None = None
    elif kind == "u" and depth.dtype.itemsize >= 2:
        metres = depth.astype(np.float64) * depth_scale
        unit = float(depth_scale)
    elif kind in "ui" and depth.dtype.itemsize == 1:
        raise FrameFileError(
            f"depth file {path} is 8-bit, which cannot hold depth: give 16-bit depth (PNG or "
            ".npy, units times --depth-scale), or float metres (EXR or .npy)"
        )
    else:
        raise FrameFileError(
            f"depth file {path} holds {depth.dtype} values: give float metres or unsigned "
            "16-bit units (times --depth-scale)"
        )
    metres[~np.isfinite(metres) | (metres < 0.0)] = 0.0
    return np.ascontiguousarray(metres, dtype=np.float32), unit


def check_depth_scale(depth_scale: float) -> float:
    """``depth_scale`` if it is a positive finite number of metres per unit."""
    if not (isinstance(depth_scale, int | float) and math.isfinite(depth_scale)) or (
        depth_scale <= 0
    ):
        raise FrameFileError(
            f"depth scale {depth_scale!r} is not a positive number of metres per depth unit: "
            "give e.g. 0.001 for millimetres"
        )
    return float(depth_scale)


def parse_intrinsics(text: str) -> tuple[float, float, float, float]:
    """``"fx,fy,cx,cy"`` as four numbers (fx, fy above 0); FrameFileError otherwise."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != 4 or not all(math.isfinite(v) for v in values):
        raise FrameFileError(f"--intrinsics {text!r} is not four numbers: {_INTRINSICS_HELP}")
    fx, fy, cx, cy = values
    if fx <= 0 or fy <= 0:
        raise FrameFileError(
            f"--intrinsics {text!r}: the focal lengths fx, fy must be above 0: {_INTRINSICS_HELP}"
        )
    return fx, fy, cx, cy


def intrinsics_from_json(path: str | os.PathLike[str]) -> Intrinsics:
    """The intrinsics in a JSON file: its ``intrinsics`` object (``armvision sim snapshot``'s
    ground_truth.json), ``camera.intrinsics`` (a calibration file) or the file's object itself
    (``Intrinsics.to_dict()``)."""
    path = Path(path)
    raw = _read_bytes(path, "intrinsics")
    try:
        data = json.loads(raw.tobytes().decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise FrameFileError(
            f"intrinsics file {path} is not JSON ({str(exc).splitlines()[0]}): {_INTRINSICS_HELP}"
        ) from None
    found: Any = None
    if isinstance(data, dict):
        camera = data.get("camera")
        for candidate in (
            data.get("intrinsics"),
            camera.get("intrinsics") if isinstance(camera, dict) else None,
            data,
        ):
            if isinstance(candidate, dict) and "fx" in candidate:
                found = candidate
                break
    if found is None:
        raise FrameFileError(f"intrinsics file {path} has no intrinsics in it: {_INTRINSICS_HELP}")
    try:
        coeffs = [float(c) for c in found.get("coeffs", [0.0] * 5)] + [0.0] * 5
        intr = Intrinsics(
            width=int(found["width"]),
            height=int(found["height"]),
            fx=float(found["fx"]),
            fy=float(found["fy"]),
            ppx=float(found["ppx"]),
            ppy=float(found["ppy"]),
            model=str(found.get("model", "none")),
            coeffs=(coeffs[0], coeffs[1], coeffs[2], coeffs[3], coeffs[4]),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise FrameFileError(
            f"intrinsics file {path}: its intrinsics lack or mistype {exc}: {_INTRINSICS_HELP}"
        ) from None
    numbers = (intr.fx, intr.fy, intr.ppx, intr.ppy)
    if not all(math.isfinite(v) for v in numbers) or intr.fx <= 0 or intr.fy <= 0:
        raise FrameFileError(f"intrinsics file {path}: fx, fy, ppx, ppy are not all sensible")
    return intr


def _intrinsics(
    intrinsics: Intrinsics | Sequence[float] | str, width: int, height: int
) -> Intrinsics:
    """The intrinsics given, as an :class:`Intrinsics` at the image's size."""
    if isinstance(intrinsics, Intrinsics):
        intr = intrinsics
        source = "the intrinsics"
    elif isinstance(intrinsics, str) and "," not in intrinsics:
        intr = intrinsics_from_json(intrinsics)
        source = f"the intrinsics in {intrinsics}"
    else:
        if isinstance(intrinsics, str):
            fx, fy, cx, cy = parse_intrinsics(intrinsics)
        else:
            fx, fy, cx, cy = parse_intrinsics(",".join(str(v) for v in intrinsics))
        return _inside(Intrinsics(width, height, fx, fy, cx, cy), "--intrinsics")
    if (intr.width, intr.height) != (width, height):
        raise FrameFileError(
            f"{source} are for {intr.width}x{intr.height} but the images are {width}x{height}: "
            "give the intrinsics of the images' size"
        )
    return _inside(intr, source)


def _inside(intr: Intrinsics, source: str) -> Intrinsics:
    if not (0.0 <= intr.ppx <= intr.width and 0.0 <= intr.ppy <= intr.height):
        raise FrameFileError(
            f"{source}: the principal point ({intr.ppx:g}, {intr.ppy:g}) is outside the "
            f"{intr.width}x{intr.height} image: give the intrinsics at the image's size"
        )
    return intr


def load_rgbd(
    color_path: str | os.PathLike[str],
    depth_path: str | os.PathLike[str],
    depth_scale: float = DEFAULT_DEPTH_SCALE,
    intrinsics: Intrinsics | Sequence[float] | str = "",
    timestamp: float = 0.0,
    index: int = 0,
) -> RGBDFrame:
    """One :class:`RGBDFrame` from a colour file and a depth file aligned to it.

    ``depth_scale``: metres per unit of integer depth (0.001: millimetres); float depth is
    metres already. ``intrinsics``: ``"fx,fy,cx,cy"`` or (fx, fy, cx, cy) at the images' size,
    an :class:`Intrinsics`, or the path of a JSON file holding them (see
    :func:`intrinsics_from_json`). FrameFileError, one line, on any bad input.
    """
    return load_rgbd_with_unit(color_path, depth_path, depth_scale, intrinsics, timestamp, index)[0]


def load_rgbd_with_unit(
    color_path: str | os.PathLike[str],
    depth_path: str | os.PathLike[str],
    depth_scale: float = DEFAULT_DEPTH_SCALE,
    intrinsics: Intrinsics | Sequence[float] | str = "",
    timestamp: float = 0.0,
    index: int = 0,
) -> tuple[RGBDFrame, float | None]:
    """:func:`load_rgbd`, and the scale applied to the depth file's values (None: float
    metres; see :func:`load_depth`)."""
    check_depth_scale(depth_scale)
    if isinstance(intrinsics, str) and "," in intrinsics:
        parse_intrinsics(intrinsics)  # a typo is reported before the images are read
    elif isinstance(intrinsics, str) and not intrinsics.strip():
        raise FrameFileError(f"no intrinsics given: {_INTRINSICS_HELP}")
    color = load_color(color_path)
    depth, unit = load_depth(depth_path, depth_scale)
    (h, w), (dh, dw) = color.shape[:2], depth.shape
    if (h, w) != (dh, dw):
        raise FrameFileError(
            f"colour {color_path} is {w}x{h} but depth {depth_path} is {dw}x{dh}: resize or "
            "align the depth to the colour image first (depth must be registered to colour)"
        )
    frame = RGBDFrame(
        color=color,
        depth=depth,
        intrinsics=_intrinsics(intrinsics, w, h),
        timestamp=float(timestamp),
        index=int(index),
    )
    return frame, unit
