"""A software RealSense (``rs.software_device``) with a depth and a colour sensor, for tests.

librealsense's software device runs the SDK's own syncer, align, filters and recorder on frames a
test injects, so RealSenseCamera's processing is tested without hardware.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from armvision.camera.frames import Intrinsics
from armvision.camera.realsense import intrinsics_to_rs

rs = pytest.importorskip("pyrealsense2", reason="pyrealsense2 is not installed")

FPS = 30


def _video_stream(stream: Any, fmt: Any, bpp: int, intr: Intrinsics, uid: int) -> Any:
    vs = rs.video_stream()
    vs.type, vs.index, vs.uid = stream, 0, uid
    vs.width, vs.height, vs.fps, vs.bpp, vs.fmt = intr.width, intr.height, FPS, bpp, fmt
    vs.intrinsics = intrinsics_to_rs(intr)
    return vs


class SoftwareRig:
    """A software D435i: depth z16 and colour rgb8 streams with extrinsics depth -> colour.

    ``T_color_depth`` (4x4) is the pose of the depth camera in the colour camera's frame, so
    p_color = T_color_depth @ p_depth, as librealsense's extrinsics from depth to colour.
    """

    def __init__(
        self,
        depth_intr: Intrinsics,
        color_intr: Intrinsics,
        T_color_depth: NDArray[np.float64],
        depth_unit: float = 0.001,
        serial: str = "000000000001",
    ) -> None:
        self.depth_intr, self.color_intr, self.depth_unit = depth_intr, color_intr, depth_unit
        self.device = rs.software_device()
        # Pair depth and colour by timestamp, set up before the sensors as librealsense's own
        # syncer tests (unit-tests/syncer/sw.py) do.
        self.device.create_matcher(rs.matchers.default)
        self.device.register_info(rs.camera_info.name, "Intel RealSense D435I (software)")
        self.device.register_info(rs.camera_info.serial_number, serial)
        self.depth_sensor = self.device.add_sensor("Stereo Module")
        self.color_sensor = self.device.add_sensor("RGB Camera")
        self.depth_profile = self.depth_sensor.add_video_stream(
            _video_stream(rs.stream.depth, rs.format.z16, 2, depth_intr, 0)
        ).as_video_stream_profile()
        self.color_profile = self.color_sensor.add_video_stream(
            _video_stream(rs.stream.color, rs.format.rgb8, 3, color_intr, 1)
        ).as_video_stream_profile()
        self.depth_sensor.add_read_only_option(rs.option.depth_units, depth_unit)
        extrinsics = rs.extrinsics()
        # librealsense stores the rotation column-major (rsutil.h rs2_transform_point_to_point).
        extrinsics.rotation = [float(r) for r in T_color_depth[:3, :3].ravel(order="F")]
        extrinsics.translation = [float(t) for t in T_color_depth[:3, 3]]
        self.depth_profile.register_extrinsics_to(self.color_profile, extrinsics)
        self._buffers: list[np.ndarray] = []  # librealsense reads injected pixels until released
        self._started: list[Any] = []
        self.syncer: Any = None
        self.frame_number = -1

    def start(self, recorder: Any = None) -> None:
        """Open and start both sensors into a syncer, or, given a ``rs.recorder``, its sensors."""
        if recorder is None:
            sensors = [self.depth_sensor, self.color_sensor]
        else:
            by_name = {s.get_info(rs.camera_info.name): s for s in recorder.query_sensors()}
            sensors = [by_name["Stereo Module"], by_name["RGB Camera"]]
        # Big queues so no frame is dropped (librealsense's default queue size is 1).
        self.syncer = rs.syncer(100) if recorder is None else rs.frame_queue(100)
        for sensor, profile in zip(sensors, [self.depth_profile, self.color_profile]):
            sensor.open(profile)
            sensor.start(self.syncer)
            self._started.append(sensor)
        if recorder is None:
            # The syncer passes the very first frame on alone before it knows both streams.
            self.inject(
                np.zeros((self.depth_intr.height, self.depth_intr.width), np.uint16),
                np.zeros((self.color_intr.height, self.color_intr.width, 3), np.uint8),
                *self.next_stamp(),
            )
            while self.syncer.try_wait_for_frames(200)[0]:
                pass

    def stop(self) -> None:
        for sensor in self._started:
            sensor.stop()
            sensor.close()
        self._started.clear()
        self.syncer = None

    def inject(
        self,
        depth_units: NDArray[np.uint16],
        color: NDArray[np.uint8],
        frame_number: int,
        timestamp_ms: float,
    ) -> None:
        """Hand one depth (z16 units) and one colour (RGB) image to the sensors."""
        for sensor, profile, pixels, bpp in (
            (self.depth_sensor, self.depth_profile, depth_units, 2),
            (self.color_sensor, self.color_profile, color, 3),
        ):
            pixels = np.ascontiguousarray(pixels)
            self._buffers.append(pixels)
            frame = rs.software_video_frame()
            frame.pixels = pixels
            frame.bpp = bpp
            frame.stride = pixels.shape[1] * bpp
            frame.timestamp = timestamp_ms
            frame.domain = rs.timestamp_domain.hardware_clock
            frame.frame_number = frame_number
            frame.profile = profile
            if bpp == 2:
                frame.depth_units = self.depth_unit
            sensor.on_video_frame(frame)

    def next_stamp(self) -> tuple[int, float]:
        """The next frame number and its timestamp (ms): 0 at 0, then 1000/FPS apart, because
        librealsense's syncer expects frames every 1000/FPS ms (unit-tests/syncer)."""
        self.frame_number += 1
        return self.frame_number, self.frame_number * 1000.0 / FPS

    def frameset(self, depth_units: NDArray[np.uint16], color: NDArray[np.uint8]) -> Any:
        """Inject one pair and return the syncer's frameset holding both (an rs.composite_frame).

        The pair gets the next frame number and timestamp: librealsense's syncer pairs reliably
        only frames that follow each other at the stream's rate; if it still passes them on
        separately, the pair is injected again as the next frame.
        """
        for _ in range(3):
            number, timestamp_ms = self.next_stamp()
            self.inject(depth_units, color, number, timestamp_ms)
            while True:
                ok, frameset = self.syncer.try_wait_for_frames(500)
                if not ok:
                    break
                numbers = {f.get_frame_number() for f in frameset}
                if frameset.size() == 2 and numbers == {number}:
                    return frameset
        raise AssertionError("librealsense's syncer did not pair the depth and colour frames")
