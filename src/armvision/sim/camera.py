"""SimCamera: the simulated D435i, rendering colour and metric depth from a SimWorld.

Colour and depth come from one offscreen OpenGL render of the world's ``d435i`` camera (so they
are aligned exactly, like librealsense's ``align`` to colour), then depth passes through
:func:`realsense_depth_model`: Intel's RMS error growing with z squared, 1 mm quantisation, no
data at depth discontinuities and outside the working range.

With ``sim.camera_effects`` (on in the cluttered profile) the frames also carry the real
D435's habits measured on ClearGrasp's real frames (``armvision.eval.clear_depth``): on clear
plastic (geoms with ``rgba`` alpha < 1, whose depth MuJoCo does not write, so the plain render
sees the surface behind) a second render with those geoms opaque gives the true surface, and
each clear pixel is missing, behind (the plain render), wrong (true + a measured error) or
good (true), in blobs; speckle holes; flying pixels (depth between the near and the far side)
at depth edges; per-frame exposure and white-balance gains. Their random draws come from a
generator seeded by the world's seed and the frame index, so a frame is repeatable.

Rendering needs OpenGL without a display: EGL (``MUJOCO_GL=egl``, Mesa's llvmpipe where there
is no GPU) or OSMesa (``MUJOCO_GL=osmesa``).
"""

from __future__ import annotations

import math
import os
import threading
import time
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from armvision.camera.frames import Intrinsics, RGBDFrame, depth_rms_error
from armvision.config import CameraConfig, SimConfig
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


#: Deciles (0, 10, ..., 100 %) of raw - true (m) on the "wrong" clear pixels of ClearGrasp's
#: four real D435 frames, pooled (armvision.eval.clear_depth.measure_real).
CLEAR_WRONG_DECILES_M = (
    -0.0435, 0.0103, 0.0112, 0.0122, 0.0132, 0.0142, 0.0151, 0.0161, 0.0173, 0.0186, 0.0198
)  # fmt: skip
#: A clear pixel: the opaque render is nearer than the plain one by more than this (m).
CLEAR_SEPARATION_M = 5e-4
BLOB_CELL_PX = 12  # the size of the clear-plastic blobs (missing, behind, ...) at 480 rows
_FLYING_KERNEL = np.ones((5, 5), np.uint8)


@dataclass(frozen=True)
class ClearTruth:
    """What the clear-plastic model worked from in the last frame: the clear pixels, the true
    z of the clear surfaces (the render with them opaque) and the plain render's z (behind)."""

    clear: NDArray[np.bool_]
    z_true: NDArray[np.float64]
    z_behind: NDArray[np.float64]


def _blobs(rng: np.random.Generator, shape: tuple[int, int]) -> NDArray[np.float32]:
    """A smooth random field (blobs ~BLOB_CELL_PX wide), for spatially coherent choices."""
    h, w = shape
    cell = max(2, round(BLOB_CELL_PX * h / 480))
    coarse = rng.standard_normal((h // cell + 2, w // cell + 2)).astype(np.float32)
    return np.asarray(cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC), np.float32)


def _lowest(field: NDArray[np.float32], where: NDArray[np.bool_], count: int) -> NDArray[np.bool_]:
    """The ``count`` pixels of ``where`` with the lowest ``field``."""
    out = np.zeros(where.shape, dtype=bool)
    idx = np.flatnonzero(where)
    if count <= 0 or idx.size == 0:
        return out
    count = min(count, idx.size)
    pick = np.argpartition(field.ravel()[idx], count - 1)[:count]
    out.ravel()[idx[pick]] = True
    return out


def clear_depth_model(
    depth: NDArray[np.float32],
    truth: ClearTruth,
    rng: np.random.Generator,
    sim: SimConfig,
) -> NDArray[np.float32]:
    """Replace the depth of clear pixels in a :func:`realsense_depth_model` output.

    Every clear pixel is sorted, in blobs, into behind (``depth`` as rendered, the surface
    behind), wrong (true z + an error drawn from ``CLEAR_WRONG_DECILES_M``) and good (true z),
    in the shares ``clear_behind``, ``clear_wrong`` and the rest, of the pixels left once
    ``clear_missing`` of them (counting those the edge and range model already dropped) read 0.
    Other pixels are not touched.
    """
    out = depth.copy()
    clear = truth.clear
    n = int(clear.sum())
    if n == 0:
        return out
    split = _blobs(rng, clear.shape)
    holes = _blobs(rng, clear.shape)
    u = rng.uniform(size=clear.shape)
    present = max(1.0 - sim.clear_missing, 1e-9)
    rank = np.zeros(clear.shape, dtype=np.float64)
    idx = np.flatnonzero(clear)
    order = np.argsort(split.ravel()[idx], kind="stable")
    rank.ravel()[idx[order]] = (np.arange(n) + 0.5) / n
    behind = clear & (rank < sim.clear_behind / present)
    wrong = clear & ~behind & (rank < (sim.clear_behind + sim.clear_wrong) / present)
    good = clear & ~behind & ~wrong
    z = truth.z_true
    err = np.interp(u, np.linspace(0.0, 1.0, len(CLEAR_WRONG_DECILES_M)), CLEAR_WRONG_DECILES_M)
    ok = np.isfinite(z) & (depth > 0)  # keep the edge and range dropouts of the depth model
    step = DEPTH_UNIT_M
    out[wrong & ok] = (np.round((z + err) / step) * step)[wrong & ok]
    out[good & ok] = (np.round(z / step) * step)[good & ok]
    dropped = clear & (out <= 0)
    extra = round(sim.clear_missing * n) - int(dropped.sum())
    out[_lowest(holes, clear & ~dropped, extra)] = 0.0
    return out.astype(np.float32)


def flying_pixels(
    depth: NDArray[np.float32],
    z_true: NDArray[np.floating],
    rng: np.random.Generator,
    share: float,
) -> NDArray[np.float32]:
    """Give ``share`` of the pixels dropped at depth edges a depth between the edge's near and
    far side (within 2 px), as the D435's aligned depth does, instead of 0."""
    if share <= 0.0:
        return depth
    z = np.where(np.isfinite(z_true), z_true, 0.0).astype(np.float32)
    near = cv2.erode(np.where(z > 0, z, np.float32(1e3)), _FLYING_KERNEL)
    far = cv2.dilate(z, _FLYING_KERNEL)
    edge = depth_edges(z_true) & (depth <= 0) & (far > 0) & (near < 1e3)
    fly = edge & (rng.uniform(size=depth.shape) < share)
    mix = near + rng.uniform(0.1, 0.9, size=depth.shape).astype(np.float32) * (far - near)
    out = depth.copy()
    out[fly] = (np.round(mix / DEPTH_UNIT_M) * DEPTH_UNIT_M)[fly]
    return out.astype(np.float32)


def speckle_holes(
    depth: NDArray[np.float32], rng: np.random.Generator, share: float
) -> NDArray[np.float32]:
    """Drop ``share`` of the pixels in small holes (2x2 px) scattered over the image."""
    if share <= 0.0:
        return depth
    seeds = (rng.uniform(size=depth.shape) < share / 4.0).astype(np.uint8)
    holes = cv2.dilate(seeds, np.ones((2, 2), np.uint8), anchor=(0, 0)).astype(bool)
    out = depth.copy()
    out[holes] = 0.0
    return out.astype(np.float32)


def colour_gains(
    color: NDArray[np.uint8], rng: np.random.Generator, exposure: float, white_balance: float
) -> NDArray[np.uint8]:
    """One frame's auto-exposure gain (1 sigma ``exposure``) and white-balance gains per
    channel (1 sigma ``white_balance``), each kept within 0.5-1.5."""
    if exposure <= 0.0 and white_balance <= 0.0:
        return color
    gain = np.clip(1.0 + exposure * rng.standard_normal(), 0.5, 1.5)
    gains = np.clip(1.0 + white_balance * rng.standard_normal(3), 0.5, 1.5) * gain
    return np.clip(color * gains.astype(np.float32), 0, 255).astype(np.uint8)


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

    def update_opaque(self, data: mujoco.MjData, geoms: NDArray[np.intp]) -> None:
        """:meth:`update` with ``geoms`` drawn opaque (so they write depth); the model's
        colours are put back before returning (hold the world lock while calling)."""
        alpha = self._model.geom_rgba[geoms, 3].copy()
        try:
            self._model.geom_rgba[geoms, 3] = 1.0
            self.update(data)
        finally:
            self._model.geom_rgba[geoms, 3] = alpha

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
        self._seed = [world.seed] if seed is None else [seed]
        self.effects = world.config.sim.camera_effects_on
        # Clear or tinted geoms (0 < alpha < 1) in a visible group.
        m = world.model
        visible = np.asarray(mujoco.MjvOption().geomgroup, dtype=bool)[m.geom_group.clip(0, 5)]
        self._clear_geoms = np.flatnonzero(
            (m.geom_rgba[:, 3] > 0) & (m.geom_rgba[:, 3] < 1) & visible
        )
        #: The clear-plastic model's inputs for the last frame read (effects on only).
        self.last_clear_truth: ClearTruth | None = None

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
            if self.effects:
                color_out, depth = self._with_effects(color, z)
            else:
                color_out = self._noisy_color(color)
                depth = realsense_depth_model(
                    z,
                    self._rng if self.depth_noise else None,
                    self.world.config.sim.depth_min,
                    self.world.config.sim.depth_max,
                )
            frame = RGBDFrame(
                color=color_out,
                depth=depth,
                intrinsics=self._intrinsics,
                timestamp=timestamp,
                index=self._index,
            )
            if self._first_time is None:
                self._first_time = timestamp
            self._index += 1
            return frame

    def _with_effects(
        self, color: NDArray[np.uint8], z: NDArray[np.float64]
    ) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
        """Colour and depth of one frame with the real camera's habits (render lock held)."""
        assert self._renderer is not None
        sim = self.world.config.sim
        rng = np.random.default_rng([*self._seed, 0xC1EA, self._index])
        z_true = z
        truth = None
        if self._clear_geoms.size:
            with self.world.lock:
                self._renderer.update_opaque(self.world.data, self._clear_geoms)
            z_true = self._renderer.render()[1]
            with np.errstate(invalid="ignore"):
                clear = np.isfinite(z_true) & ~(z_true >= z - CLEAR_SEPARATION_M)
            truth = ClearTruth(clear, z_true, z)
        self.last_clear_truth = truth
        depth = realsense_depth_model(
            z, rng if self.depth_noise else None, sim.depth_min, sim.depth_max
        )
        depth = flying_pixels(depth, z, rng, sim.flying_pixels)
        if truth is not None:
            depth = clear_depth_model(depth, truth, rng, sim)
        depth = speckle_holes(depth, rng, sim.speckle_holes)
        color = colour_gains(color, rng, sim.exposure_jitter, sim.white_balance_jitter)
        if self.color_noise > 0.0:
            noise = rng.standard_normal(color.shape, dtype=np.float32) * self.color_noise
            color = np.clip(color + noise, 0, 255).astype(np.uint8)
        return color, depth

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
