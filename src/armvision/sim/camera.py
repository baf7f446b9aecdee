"""SimCamera: the simulated D435i, rendering colour and metric depth from a SimWorld.

Colour and depth come from one offscreen OpenGL render of the world's ``d435i`` camera (so they
are aligned exactly, like librealsense's ``align`` to colour), then depth passes through
:func:`realsense_depth_model`: Intel's RMS error growing with z squared, 1 mm quantisation, no
data at depth discontinuities and outside the working range.

Rendering needs OpenGL without a display: EGL (``MUJOCO_GL=egl``, Mesa's llvmpipe where there
is no GPU) or OSMesa (``MUJOCO_GL=osmesa``).
"""

from __future__ import annotations

import math
import os
import threading
import time

import cv2
import numpy as np
from numpy.typing import NDArray

from armvision.camera.frames import Intrinsics, RGBDFrame, depth_rms_error
from armvision.config import CameraConfig
from armvision.errors import SimulationError
from armvision.sim._mujoco import GL_HELP, mujoco
from armvision.sim.world import SimWorld

DEPTH_UNIT_M = 0.001  # the D435's default depth unit: 1 mm
#: A jump between neighbouring pixels larger than this fraction of the depth is a
#: discontinuity (an object's silhouette); stereo matching fails there, so the pixels on both
#: sides read 0.
DEPTH_EDGE_RELATIVE_JUMP = 0.03
_BAND_KERNEL = np.ones((3, 3), np.uint8)


def depth_edges(
    z: NDArray[np.floating], relative_jump: float = DEPTH_EDGE_RELATIVE_JUMP
) -> NDArray[np.bool_]:
    """Pixels within 2 px of a depth discontinuity (neighbours differ by > relative_jump x z)."""
    mask = np.zeros(z.shape, dtype=bool)
    dz_x = np.abs(np.diff(z, axis=1))
    dz_y = np.abs(np.diff(z, axis=0))
    near_x = np.minimum(z[:, 1:], z[:, :-1]) * relative_jump
    near_y = np.minimum(z[1:, :], z[:-1, :]) * relative_jump
    jump_x, jump_y = dz_x > near_x, dz_y > near_y
    mask[:, 1:] |= jump_x
    mask[:, :-1] |= jump_x
    mask[1:, :] |= jump_y
    mask[:-1, :] |= jump_y
    # Stereo matching fails in a band a few pixels wide, not on a one-pixel line.
    return cv2.dilate(mask.view(np.uint8), _BAND_KERNEL).view(bool)


def realsense_depth_model(
    z_true: NDArray[np.floating],
    rng: np.random.Generator | None,
    depth_min: float = 0.28,
    depth_max: float = 3.0,
) -> NDArray[np.float32]:
    """A D435-like depth image from true z-depth (m): noise, 1 mm steps, 0 = no data.

    Gaussian noise with :func:`depth_rms_error` (skipped when ``rng`` is None), rounding to
    ``DEPTH_UNIT_M``, and zeros at discontinuities (:func:`depth_edges`) and outside
    [depth_min, depth_max].
    """
    z = np.asarray(z_true, dtype=np.float64)
    invalid = (z < depth_min) | (z > depth_max) | ~np.isfinite(z) | depth_edges(z)
    if rng is not None:
        z = z + rng.standard_normal(z.shape) * depth_rms_error(z)
    z = np.round(z / DEPTH_UNIT_M) * DEPTH_UNIT_M
    z[invalid] = 0.0
    return z.astype(np.float32)


class _OffscreenRGBD:
    """One OpenGL context rendering colour and depth of a fixed camera in a single pass."""

    def __init__(self, model: mujoco.MjModel, camera_id: int, width: int, height: int) -> None:
        backend = os.environ.get("MUJOCO_GL", "(unset)")
        try:
            self._gl = mujoco.GLContext(width, height)
            self._gl.make_current()
            self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        except Exception as exc:  # no display, no EGL device, missing Mesa drivers ...
            raise SimulationError(
                f"cannot render: no OpenGL context for MUJOCO_GL={backend}"
                f" ({type(exc).__name__}: {exc}); {GL_HELP}"
            ) from exc
        self.width, self.height = width, height
        self._model = model
        self.scene = mujoco.MjvScene(model, maxgeom=2000)
        self._option = mujoco.MjvOption()
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._camera.fixedcamid = camera_id
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        # MuJoCo >= 3.3 renders with reversed z (1 at the near plane); older versions do not.
        self._reversed_z = hasattr(self._context, "readDepthMap")
        if self._reversed_z:
            self._context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.empty((height, width, 3), dtype=np.uint8)
        self._depth = np.empty((height, width), dtype=np.float32)

    def update(self, data: mujoco.MjData) -> None:
        """Copy the geometry to draw out of ``data`` (hold the world lock while calling)."""
        mujoco.mjv_updateScene(
            self._model,
            data,
            self._option,
            None,
            self._camera,
            mujoco.mjtCatBit.mjCAT_ALL,
            self.scene,
        )

    def render(self) -> tuple[NDArray[np.uint8], NDArray[np.float64]]:
        """Colour (H, W, 3) uint8 and z-depth (H, W) metres, rows top to bottom."""
        self._gl.make_current()
        mujoco.mjr_render(self._rect, self.scene, self._context)
        mujoco.mjr_readPixels(self._rgb, self._depth, self._rect, self._context)
        return np.flipud(self._rgb).copy(), self._linear_depth(np.flipud(self._depth))

    def _linear_depth(self, buffer: NDArray[np.float32]) -> NDArray[np.float64]:
        """Metric z from the depth buffer by undoing the projection (as mujoco.Renderer does)."""
        extent = self._model.stat.extent
        near = np.float32(self._model.vis.map.znear * extent)
        far = np.float32(self._model.vis.map.zfar * extent)
        d = buffer.astype(np.float64)
        if not self._reversed_z:  # classic OpenGL depth in [0, 1], 0 at the near plane
            return near / (1.0 - d * (1.0 - near / far))
        c = -(far + near) / (far - near)
        e = -(np.float32(2.0) * far * near) / (far - near)
        c, e = np.float32(-0.5) * c - np.float32(0.5), np.float32(-0.5) * e
        with np.errstate(divide="ignore"):
            return e / (d + c)

    def close(self) -> None:
        if getattr(self, "_context", None) is not None and self._gl is not None:
            self._gl.make_current()
            self._context.free()
            self._context = None
        if getattr(self, "_gl", None) is not None:
            self._gl.free()
            self._gl = None


class SimCamera:
    """The simulated RealSense D435i colour + aligned depth stream (the Camera interface).

    Intrinsics are those of the D435i colour stream: fx = fy = 615 px at 640x480 (scaled
    with the height), principal point at the image centre. Frames come every 1/fps seconds of
    simulation time; in lockstep mode :meth:`read` advances the world to the next frame time.
    ``depth_noise`` (default: ``config.sim.depth_noise``) switches the D435 depth model on;
    ``color_noise`` is the standard deviation of Gaussian pixel noise in grey levels.
    """

    #: Stands in for the RealSense serial number in saved files (e.g. the calibration).
    serial = "sim"

    def __init__(
        self,
        world: SimWorld,
        config: CameraConfig | None = None,
        depth_noise: bool | None = None,
        color_noise: float = 1.0,
        seed: int | None = None,
    ) -> None:
        self.world = world
        self.config = config if config is not None else world.config.camera
        self.depth_noise = world.config.sim.depth_noise if depth_noise is None else depth_noise
        self.color_noise = float(color_noise)
        self._rng = np.random.default_rng([world.seed, 0xCA3E] if seed is None else seed)
        width, height = self.config.width, self.config.height
        fovy = math.radians(float(world.model.cam_fovy[world.camera_id]))
        f = (height / 2.0) / math.tan(fovy / 2.0)
        # MuJoCo's frustum is centred on the image; with pixel centres at integers (OpenCV)
        # the centre is at (W - 1) / 2, (H - 1) / 2.
        self._intrinsics = Intrinsics(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)
        self.period = 1.0 / float(self.config.fps)
        self._renderer: _OffscreenRGBD | None = None
        self._first_time: float | None = None
        self._slot = 0
        self._index = 0
        self._render_lock = threading.Lock()

    @property
    def intrinsics(self) -> Intrinsics:
        return self._intrinsics

    def start(self) -> None:
        """Create the offscreen renderer; SimulationError naming MUJOCO_GL if GL is missing."""
        if self._renderer is None:
            self._renderer = _OffscreenRGBD(
                self.world.model, self.world.camera_id, self.config.width, self.config.height
            )

    def stop(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> SimCamera:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def read(self, timeout_s: float = 1.0) -> RGBDFrame:
        """The next frame: one frame period of simulation time after the last one read.

        Lockstep: advances the world to that time. Realtime: waits for it, at most
        ``timeout_s`` seconds of wall-clock time.
        """
        if self._renderer is None:
            raise SimulationError("SimCamera is not started: call start() or use `with camera:`")
        with self._render_lock:
            if self._first_time is not None:
                # Frames fall on a fixed grid from the first one, so timestamps do not drift;
                # the next one is the slot after the last read, or the newest slot already
                # passed if the world ran on meanwhile (a real camera drops those frames too).
                elapsed_slots = math.floor((self.world.time - self._first_time) / self.period)
                self._slot = max(self._slot + 1, elapsed_slots)
                due = self._first_time + self._slot * self.period
                if self.world.mode == "lockstep":
                    self.world.run_until(due)
                else:
                    self._wait_for(due, timeout_s)
            with self.world.lock:
                timestamp = self.world.time
                self._renderer.update(self.world.data)
            color, z = self._renderer.render()
            frame = RGBDFrame(
                color=self._noisy_color(color),
                depth=realsense_depth_model(
                    z,
                    self._rng if self.depth_noise else None,
                    self.world.config.sim.depth_min,
                    self.world.config.sim.depth_max,
                ),
                intrinsics=self._intrinsics,
                timestamp=timestamp,
                index=self._index,
            )
            if self._first_time is None:
                self._first_time = timestamp
            self._index += 1
            return frame

    def render_true_depth(self) -> NDArray[np.float64]:
        """The exact z-depth of the current state (no noise, no dropouts), for ground truth."""
        if self._renderer is None:
            raise SimulationError("SimCamera is not started: call start() or use `with camera:`")
        with self._render_lock:
            with self.world.lock:
                self._renderer.update(self.world.data)
            return self._renderer.render()[1]

    def _wait_for(self, t: float, timeout_s: float) -> None:
        try:
            self.world.run_until(t, timeout_s=timeout_s)
        except SimulationError as exc:
            raise SimulationError(f"no new simulated frame within {timeout_s} s: {exc}") from exc
        # time.sleep(0) lets the physics thread take the lock back between frames
        time.sleep(0)

    def _noisy_color(self, color: NDArray[np.uint8]) -> NDArray[np.uint8]:
        if self.color_noise <= 0.0:
            return color
        noise = self._rng.standard_normal(color.shape, dtype=np.float32) * self.color_noise
        return np.clip(color + noise, 0, 255).astype(np.uint8)
