"""RealSenseCamera: an Intel RealSense D435i (or a recording of one) through pyrealsense2.

This is the only module that imports ``pyrealsense2``, and only inside functions, so importing it
works without the SDK; the SDK is needed once a camera is constructed. Per frame the camera runs
librealsense's own code: optional depth filters (in the order of librealsense's
rs-post-processing example: depth to disparity, spatial, temporal, back to depth, hole filling),
``rs.align`` of depth to the colour stream, then :class:`FrameProcessor` converts the aligned
frameset to an :class:`~armvision.camera.frames.RGBDFrame` (RGB uint8, float32 metres).

Recordings: librealsense 2.59 writes ROS 2 ``.db3`` files (``enable_record_to_file`` refuses other
extensions) and plays back both ``.db3`` and the older ROS 1 ``.bag`` files.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from armvision.camera.frames import Intrinsics, RGBDFrame
from armvision.config import CameraConfig
from armvision.errors import HardwareError

_NOT_STARTED = "RealSenseCamera is not started: call start() or use `with camera:`"
#: A recording has ended when its reader stopped and no frame came for this long.
_END_GRACE_S = 0.3

_INSTALL_HINT = (
    "install the RealSense SDK's Python bindings: `pip install pyrealsense2` (x86_64 wheels, and "
    "aarch64 wheels for some Python versions only; where pip finds none, build librealsense with "
    "-DBUILD_PYTHON_BINDINGS=ON) or `pip install armvision[realsense]`"
)
_PLUG_IN_HINT = (
    "plug the D435i into a USB 3 port (check with `rs-enumerate-devices` or `lsusb | grep 8086`), "
    "or set camera.bag to play back a recording, or use the simulator (--sim)"
)


def _import_rs() -> Any:
    """pyrealsense2, or a HardwareError that says how to install it."""
    try:
        import pyrealsense2 as rs
    except ImportError as exc:
        raise HardwareError(f"cannot use a RealSense camera: {exc}; {_INSTALL_HINT}") from None
    return rs


def intrinsics_to_rs(intr: Intrinsics) -> Any:
    """``intr`` as a pyrealsense2 ``rs.intrinsics`` (the inverse of ``Intrinsics.from_rs``)."""
    rs = _import_rs()
    rs_intr = rs.intrinsics()
    rs_intr.width, rs_intr.height = intr.width, intr.height
    rs_intr.fx, rs_intr.fy, rs_intr.ppx, rs_intr.ppy = intr.fx, intr.fy, intr.ppx, intr.ppy
    rs_intr.model = getattr(rs.distortion, intr.model)
    rs_intr.coeffs = [float(c) for c in intr.coeffs]
    return rs_intr


def _is_new_pair(last: tuple[int, int] | None, numbers: tuple[int, int]) -> bool:
    """Whether (colour, depth) frame numbers form a new pair: both differ from the last pair's.

    librealsense re-sends a frame together with the other stream's next one.
    """
    return last is None or (numbers[0] != last[0] and numbers[1] != last[1])


# --------------------------------------------------------------------------------------------
# Choosing a device: plain data in, a device or an error that says what to do out.


@dataclass(frozen=True)
class DeviceInfo:
    """What ``rs.context().query_devices()`` tells about one connected camera."""

    serial: str
    name: str
    usb_type: str | None  # camera_info.usb_type_descriptor, e.g. "3.2"; None if not reported


def select_device(devices: Sequence[DeviceInfo], serial: str | None) -> DeviceInfo:
    """The camera to open: the one with ``serial``, else the first; refuses one on USB 2.

    Raises HardwareError when there is no camera, the serial is not among them (the message lists
    the ones there are), or the chosen camera is connected over USB 2 (too slow for colour and
    depth at 640x480, 30 FPS).
    """
    if not devices:
        raise HardwareError(f"no RealSense camera found: {_PLUG_IN_HINT}")
    if serial is None:
        chosen = devices[0]
    else:
        matches = [d for d in devices if d.serial == str(serial)]
        if not matches:
            present = ", ".join(f"{d.serial} ({d.name})" for d in devices)
            raise HardwareError(
                f"no RealSense camera with serial number {serial}; connected: {present}. "
                "Set camera.serial to one of these (or leave it unset to use the first)."
            )
        chosen = matches[0]
    if chosen.usb_type is not None and chosen.usb_type.startswith("2"):
        raise HardwareError(
            f"RealSense {chosen.name} ({chosen.serial}) is connected over USB {chosen.usb_type}, "
            "too slow for colour and depth at 640x480, 30 FPS: plug it into a USB 3 port "
            "(blue, or marked SS) with a USB 3 cable, directly rather than through a hub."
        )
    return chosen


def connected_devices() -> tuple[str, list[DeviceInfo]]:
    """(pyrealsense2's version, the RealSense cameras connected now); HardwareError saying what
    to do if pyrealsense2 is missing or cannot list devices."""
    rs = _import_rs()
    version = getattr(rs, "__version__", "?")
    try:
        return version, _device_infos(rs, rs.context())
    except RuntimeError as exc:
        raise HardwareError(f"pyrealsense2 {version}: cannot list devices ({exc})") from None


def _device_infos(rs: Any, context: Any) -> list[DeviceInfo]:
    infos = []
    for device in context.query_devices():

        def info(key: Any, device: Any = device) -> str | None:
            return device.get_info(key) if device.supports(key) else None

        infos.append(
            DeviceInfo(
                serial=info(rs.camera_info.serial_number) or "?",
                name=info(rs.camera_info.name) or "RealSense",
                usb_type=info(rs.camera_info.usb_type_descriptor),
            )
        )
    return infos


def _video_modes(device: Any, stream: Any, fmt: Any) -> list[str]:
    """'WxH@FPS' of every mode ``device`` offers for ``stream`` in format ``fmt``."""
    modes = set()
    for sensor in device.query_sensors():
        for profile in sensor.get_stream_profiles():
            if profile.stream_type() == stream and profile.format() == fmt:
                video = profile.as_video_stream_profile()
                modes.add((video.width(), video.height(), profile.fps()))
    return [f"{w}x{h}@{fps}" for w, h, fps in sorted(modes)]


# --------------------------------------------------------------------------------------------
# Per-frame processing, shared by RealSenseCamera and the tests (which feed software devices).


class FrameProcessor:
    """Depth filters, ``rs.align`` to colour, and conversion of a frameset to an RGBDFrame.

    ``depth_scale`` metres per z16 unit (the depth sensor's ``depth_units``). The filters are
    librealsense's ``spatial_filter``, ``temporal_filter`` (both run on disparity, as
    rs-post-processing does) and ``hole_filling_filter`` (mode 1, the farthest neighbour), all
    with the SDK's default settings; they run on depth before alignment, where they were tuned.
    """

    def __init__(
        self,
        depth_scale: float,
        spatial_filter: bool = False,
        temporal_filter: bool = False,
        hole_filling: bool = False,
    ) -> None:
        rs = _import_rs()
        self._rs = rs
        self.depth_scale = float(depth_scale)
        self._filters: list[Any] = []
        if spatial_filter or temporal_filter:
            self._filters.append(rs.disparity_transform(True))
        if spatial_filter:
            self._filters.append(rs.spatial_filter())
        if temporal_filter:
            self._filters.append(rs.temporal_filter())
        if spatial_filter or temporal_filter:
            self._filters.append(rs.disparity_transform(False))
        if hole_filling:
            self._filters.append(rs.hole_filling_filter(1))
        self._align = rs.align(rs.stream.color)

    def align(self, frameset: Any) -> Any:
        """``frameset`` filtered and with depth aligned to colour (an ``rs.composite_frame``)."""
        for block in self._filters:
            frameset = block.process(frameset).as_frameset()
        return self._align.process(frameset)

    def to_rgbd(self, aligned: Any, index: int) -> RGBDFrame:
        """RGBDFrame of an aligned frameset; copies the pixels so librealsense can reuse its own.

        Depth z16 x depth_scale -> float32 metres (0 stays 0, "no data"); colour rgb8 as is,
        bgr8/rgba8/bgra8 (possible in recordings from other tools) converted to RGB.
        """
        rs = self._rs
        color_frame = aligned.get_color_frame()
        depth_frame = aligned.get_depth_frame()
        if not color_frame or not depth_frame:
            raise HardwareError("frameset lacks colour or depth: enable both streams")
        color = np.asanyarray(color_frame.get_data())
        fmt = color_frame.profile.format()
        if fmt == rs.format.rgb8:
            rgb = color.copy()
        elif fmt == rs.format.bgr8:
            rgb = np.ascontiguousarray(color[:, :, ::-1])
        elif fmt == rs.format.rgba8:
            rgb = np.ascontiguousarray(color[:, :, :3])
        elif fmt == rs.format.bgra8:
            rgb = np.ascontiguousarray(color[:, :, 2::-1])
        else:
            raise HardwareError(
                f"colour format {fmt} is not supported: record or stream colour as rgb8 or bgr8"
            )
        depth = np.asanyarray(depth_frame.get_data()).astype(np.float32)
        depth *= np.float32(self.depth_scale)
        if depth.shape != rgb.shape[:2]:
            raise HardwareError(
                f"aligned depth {depth.shape} and colour {rgb.shape[:2]} differ in size"
            )
        intr = Intrinsics.from_rs(color_frame.profile.as_video_stream_profile().get_intrinsics())
        return RGBDFrame(
            color=rgb,
            depth=depth,
            intrinsics=intr,
            timestamp=color_frame.get_timestamp() / 1000.0,  # librealsense timestamps are ms
            index=index,
        )

    def process(self, frameset: Any, index: int) -> RGBDFrame:
        """Filter, align and convert one frameset (holding a colour and a depth frame)."""
        return self.to_rgbd(self.align(frameset), index)


# --------------------------------------------------------------------------------------------


class RecordingEndedError(HardwareError):
    """A played-back recording has no more frames."""


class _Recording:
    """A .bag/.db3 recording played through its sensors, frame by frame, without the pipeline.

    librealsense's pipeline starts a playback in real time, so frames due before
    ``set_real_time(False)`` takes effect are dropped. Here the playback is paused until both
    sensors are started, and in non-real-time mode librealsense waits for each frame callback
    to return, so the bounded queue below makes the reader wait for the consumer: every frame
    is read once, in file order. Depth and colour are paired as they come: each new frame with
    the latest of the other stream, a pair once both are newer than the last pair's.
    """

    def __init__(self, rs: Any, path: str, realtime: bool) -> None:
        self._rs, self.path = rs, path
        self._context = rs.context()  # keeps the loaded device alive
        self.playback = self._context.load_device(path).as_playback()
        self.playback.set_real_time(realtime)
        self.playback.pause()
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=2)
        self._stopping = threading.Event()
        self._sensors: list[Any] = []
        profiles = {}
        for sensor in self.playback.query_sensors():
            for profile in sensor.get_stream_profiles():
                kind = profile.stream_type()
                if kind in (rs.stream.depth, rs.stream.color) and kind not in profiles:
                    profiles[kind] = (sensor, profile)
        missing = [
            n
            for k, n in ((rs.stream.depth, "depth"), (rs.stream.color, "colour"))
            if k not in profiles
        ]
        if missing:
            raise HardwareError(
                f"recording {path!r} has no {' or '.join(missing)} stream: record both colour "
                "and depth"
            )
        self.depth_sensor = profiles[rs.stream.depth][0]
        self.color_profile = profiles[rs.stream.color][1].as_video_stream_profile()
        for sensor, profile in profiles.values():
            sensor.open(profile)
            sensor.start(self._on_frame)
            self._sensors.append(sensor)
        # librealsense only builds framesets in processing blocks; this one pairs two frames.
        self._pair: tuple[Any, Any] | None = None
        self._combiner = rs.processing_block(self._combine)
        self._combined = rs.frame_queue(1)
        self._combiner.start(self._combined)
        self._latest: dict[Any, Any] = {}
        self._last_numbers: tuple[int, int] | None = None
        self.playback.resume()

    def _on_frame(self, frame: Any) -> None:
        # Runs on librealsense's reader thread; blocking here is the back-pressure.
        frame.keep()
        while not self._stopping.is_set():
            try:
                self._queue.put(frame, timeout=0.05)
                return
            except queue.Full:
                pass

    def _combine(self, frame: Any, source: Any) -> None:
        assert self._pair is not None
        source.frame_ready(source.allocate_composite_frame(list(self._pair)))

    def next_frameset(self, timeout_s: float) -> Any:
        """The next colour + depth pair as an rs.composite_frame; raises at the end or timeout."""
        rs = self._rs
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                frame = self._queue.get(timeout=_END_GRACE_S)
            except queue.Empty:
                if self.playback.current_status() == rs.playback_status.stopped:
                    raise RecordingEndedError(
                        f"recording {self.path!r} has no more frames: stop reading, or start() "
                        "the camera again to replay it"
                    ) from None
                if time.monotonic() > deadline:
                    raise HardwareError(
                        f"no frame from recording {self.path!r} within {timeout_s} s"
                    ) from None
                continue
            self._latest[frame.profile.stream_type()] = frame
            depth, color = self._latest.get(rs.stream.depth), self._latest.get(rs.stream.color)
            if depth is None or color is None:
                continue
            numbers = (color.get_frame_number(), depth.get_frame_number())
            if not _is_new_pair(self._last_numbers, numbers):
                continue
            self._last_numbers = numbers
            self._pair = (depth, color)
            self._combiner.invoke(depth)
            return self._combined.wait_for_frame(1000).as_frameset()

    def stop(self) -> None:
        self.playback.pause()
        self._stopping.set()  # lets a callback blocked on the full queue return
        for sensor in self._sensors:
            sensor.stop()
            sensor.close()
        self._sensors.clear()
        self._latest.clear()
        self._pair = None


class RealSenseCamera:
    """A RealSense D435i, or a recording of one, as an armvision :class:`Camera`.

    Streams colour (rgb8) and depth (z16) at ``width`` x ``height``, ``fps`` and aligns depth to
    colour; frames carry the colour stream's intrinsics. ``serial`` picks one of several cameras
    (None: the first). ``bag`` plays back a ``.bag``/``.db3`` recording instead of a live camera,
    by default as fast as it is read (``realtime_playback=False``) so every recorded frame is read
    once and in order. ``record_to`` records the live streams to a file (``.db3`` with
    librealsense 2.59). ``spatial_filter``, ``temporal_filter``, ``hole_filling`` switch on
    librealsense's depth filters (see :class:`FrameProcessor`).

    Example::

        with RealSenseCamera.from_config(config.camera) as camera:
            frame = camera.read(timeout_s=1.0)
    """

    def __init__(
        self,
        width: int = 640,
        height: int = 480,
        fps: int = 30,
        serial: str | None = None,
        bag: str | os.PathLike[str] | None = None,
        *,
        record_to: str | os.PathLike[str] | None = None,
        spatial_filter: bool = False,
        temporal_filter: bool = False,
        hole_filling: bool = False,
        realtime_playback: bool = False,
    ) -> None:
        if bag is not None and record_to is not None:
            raise HardwareError("a camera either plays back a recording or records, not both")
        self.width, self.height, self.fps = int(width), int(height), int(fps)
        self.serial = None if serial is None else str(serial)
        self.bag = None if bag is None else os.fspath(bag)
        self.record_to = None if record_to is None else os.fspath(record_to)
        self.spatial_filter = spatial_filter
        self.temporal_filter = temporal_filter
        self.hole_filling = hole_filling
        self.realtime_playback = realtime_playback
        self._rs = _import_rs()
        self._lock = threading.Lock()
        self._pipeline: Any = None
        self._recording: _Recording | None = None
        self._processor: FrameProcessor | None = None
        self._intrinsics: Intrinsics | None = None
        self._depth_scale: float | None = None
        self._last_numbers: tuple[int, int] | None = None
        self._index = 0

    @classmethod
    def from_config(cls, config: CameraConfig, **kwargs: Any) -> RealSenseCamera:
        """A camera for ``config.camera``; ``kwargs`` add the options the config does not hold."""
        return cls(
            width=config.width,
            height=config.height,
            fps=config.fps,
            serial=config.serial,
            bag=config.bag,
            **kwargs,
        )

    # -- properties ---------------------------------------------------------------------------

    @property
    def intrinsics(self) -> Intrinsics:
        """The colour stream's intrinsics (known once started)."""
        if self._intrinsics is None:
            raise HardwareError(_NOT_STARTED)
        return self._intrinsics

    @property
    def depth_scale(self) -> float:
        """Metres per depth unit, from the device (or the recording)."""
        if self._depth_scale is None:
            raise HardwareError(_NOT_STARTED)
        return self._depth_scale

    # -- life cycle ---------------------------------------------------------------------------

    def start(self) -> None:
        with self._lock:
            if self._pipeline is not None or self._recording is not None:
                return
            if self.bag is not None:
                self._start_playback()
            else:
                self._start_live()
            self._last_numbers = None
            self._index = 0

    def _start_playback(self) -> None:
        assert self.bag is not None
        if not os.path.isfile(self.bag):
            raise HardwareError(
                f"recording {self.bag!r} does not exist: check camera.bag (a .bag or .db3 file)"
            )
        try:
            recording = _Recording(self._rs, self.bag, self.realtime_playback)
        except RuntimeError as exc:
            raise HardwareError(
                f"cannot play back {self.bag!r}: it is not a readable RealSense recording ({exc}); "
                "record one with `record_to` or realsense-viewer"
            ) from None
        try:
            intrinsics = Intrinsics.from_rs(recording.color_profile.get_intrinsics())
            if (intrinsics.width, intrinsics.height) != (self.width, self.height):
                raise HardwareError(
                    f"recording {self.bag!r} holds colour at {intrinsics.width}x"
                    f"{intrinsics.height}, not {self.width}x{self.height}: set camera.width and "
                    "camera.height to match"
                )
            depth_scale = float(recording.depth_sensor.as_depth_sensor().get_depth_scale())
        except Exception:
            recording.stop()
            raise
        self._recording, self._intrinsics, self._depth_scale = recording, intrinsics, depth_scale
        self._processor = self._make_processor()

    def _start_live(self) -> None:
        rs = self._rs
        context = rs.context()
        chosen = select_device(_device_infos(rs, context), self.serial)
        self.serial = chosen.serial  # the camera in use, e.g. for the calibration file
        config = rs.config()
        config.enable_device(chosen.serial)
        config.enable_stream(rs.stream.color, self.width, self.height, rs.format.rgb8, self.fps)
        config.enable_stream(rs.stream.depth, self.width, self.height, rs.format.z16, self.fps)
        if self.record_to is not None:
            config.enable_record_to_file(self.record_to)
        pipeline = rs.pipeline(context)
        try:
            if not config.can_resolve(rs.pipeline_wrapper(pipeline)):
                raise self._unsupported_mode_error(context, chosen)
            profile = pipeline.start(config)
        except RuntimeError as exc:
            message = str(exc)
            if self.record_to is not None and "extension" in message:
                raise HardwareError(f"cannot record to {self.record_to!r}: {message}") from None
            if "No device connected" in message:
                raise HardwareError(
                    f"the RealSense camera disappeared ({message}): {_PLUG_IN_HINT}"
                ) from None
            raise HardwareError(f"cannot start the RealSense camera: {message}") from None
        try:
            color_profile = profile.get_stream(rs.stream.color).as_video_stream_profile()
            self._intrinsics = Intrinsics.from_rs(color_profile.get_intrinsics())
            depth_sensor = profile.get_device().first_depth_sensor()
            self._depth_scale = float(depth_sensor.get_depth_scale())
        except Exception:
            pipeline.stop()
            raise
        self._pipeline = pipeline
        self._processor = self._make_processor()

    def _make_processor(self) -> FrameProcessor:
        assert self._depth_scale is not None
        return FrameProcessor(
            self._depth_scale,
            spatial_filter=self.spatial_filter,
            temporal_filter=self.temporal_filter,
            hole_filling=self.hole_filling,
        )

    def _unsupported_mode_error(self, context: Any, chosen: DeviceInfo) -> HardwareError:
        rs = self._rs
        device = next(
            d
            for d in context.query_devices()
            if d.get_info(rs.camera_info.serial_number) == chosen.serial
        )
        colour = ", ".join(_video_modes(device, rs.stream.color, rs.format.rgb8))
        depth = ", ".join(_video_modes(device, rs.stream.depth, rs.format.z16))
        return HardwareError(
            f"RealSense {chosen.name} ({chosen.serial}) cannot stream colour rgb8 and depth "
            f"z16 at {self.width}x{self.height}@{self.fps}. Colour modes: {colour or 'none'}; "
            f"depth modes: {depth or 'none'}. Set camera.width, height and fps to a mode "
            "in both lists (640x480@30 suits a D435i)."
        )

    def stop(self) -> None:
        with self._lock:
            pipeline, self._pipeline = self._pipeline, None
            recording, self._recording = self._recording, None
            if pipeline is not None:
                pipeline.stop()  # also closes a recording file
            if recording is not None:
                recording.stop()

    def __enter__(self) -> RealSenseCamera:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- frames -------------------------------------------------------------------------------

    def read(self, timeout_s: float = 1.0) -> RGBDFrame:
        """The newest frame, waiting up to ``timeout_s`` for one newer than the last read.

        A live camera skips frames the caller was too slow for; a recording played back with
        ``realtime_playback=False`` returns every recorded colour + depth pair in order, then
        raises :class:`RecordingEndedError`.
        """
        processor, recording, pipeline = self._processor, self._recording, self._pipeline
        if processor is None or (recording is None and pipeline is None):
            raise HardwareError(_NOT_STARTED)
        if recording is not None:
            frameset = recording.next_frameset(timeout_s)
        else:
            frameset = self._newest_live_frameset(pipeline, timeout_s)
        frame = processor.process(frameset, self._index)
        self._index += 1
        return frame

    def _newest_live_frameset(self, pipeline: Any, timeout_s: float) -> Any:
        deadline = time.monotonic() + timeout_s
        while True:
            remaining_ms = int((deadline - time.monotonic()) * 1000.0)
            try:
                ok, frameset = pipeline.try_wait_for_frames(max(remaining_ms, 1))
            except RuntimeError as exc:  # stop() from another thread while waiting
                raise HardwareError(f"RealSenseCamera stopped while reading: {exc}") from None
            if not ok or remaining_ms <= 0:
                raise HardwareError(
                    f"no frame from the RealSense camera within {timeout_s} s: is it still "
                    "plugged in (USB 3)? Another program (realsense-viewer, a ROS node) may "
                    "hold it."
                )
            # Drop queued framesets for the latest one (the Camera contract: the newest frame).
            newer = pipeline.poll_for_frames()
            while newer:
                frameset, newer = newer, pipeline.poll_for_frames()
            color, depth = frameset.get_color_frame(), frameset.get_depth_frame()
            if not color or not depth:
                continue
            numbers = (color.get_frame_number(), depth.get_frame_number())
            if not _is_new_pair(self._last_numbers, numbers):
                continue
            self._last_numbers = numbers
            return frameset
