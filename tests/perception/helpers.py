"""Shared by the detector tests: a scene of placed objects rendered once and detected, and a
synthetic bench whose exact depth is known by construction."""

from __future__ import annotations

import math

import numpy as np

from armvision.camera.frames import Intrinsics, RGBDFrame
from armvision.config import Config
from armvision.geometry import inv_T, transform_points
from armvision.perception.detection import Detection, FrameContext
from armvision.perception.geometric import GeometricDetector
from armvision.sim.arm import SimArm
from armvision.sim.camera import SimCamera
from armvision.sim.scene import ObjectSpec, SceneSpec, random_camera_pose
from armvision.sim.world import SimWorld


def detect_placed(
    config: Config, seed: int, objects: tuple[ObjectSpec, ...]
) -> tuple[list[tuple[ObjectSpec, np.ndarray]], list[Detection]]:
    """``objects`` on the table with the configured camera (not jittered), settled 0.1 s,
    one frame through :class:`GeometricDetector` given the true camera pose and the encoder
    readings. Returns (each true object's spec and its centre half-way up its axis in the
    camera frame, the detections)."""
    scene = SceneSpec(random_camera_pose(config.sim, None), objects)
    with SimWorld(config, seed=seed, scene=scene) as world, SimCamera(world) as camera:
        world.advance(0.1)
        frame = camera.read()
        truth = world.ground_truth()
        q = SimArm(world).get_joint_positions()
    found = GeometricDetector(seed=seed).detect(
        frame, FrameContext(T_base_cam=truth.T_base_cam, joint_positions=q)
    )
    T_cam_base = inv_T(truth.T_base_cam)
    true = [
        (s.spec, transform_points(T_cam_base @ s.T_base_obj, [0.0, 0.0, s.spec.height / 2]))
        for s in truth.objects
    ]
    return true, found


class TiltedBench:
    """A synthetic bench: a camera ``height`` m above a table, pitched ``pitch_deg`` down,
    and the exact depth image of the table and of vertical cylinders standing on it (no
    noise), so a detector's answer can be checked against geometry known by construction."""

    INTR = Intrinsics(640, 480, 615.0, 615.0, 319.5, 239.5)

    def __init__(self, pitch_deg: float = 35.0, height: float = 0.45) -> None:
        pitch = math.radians(pitch_deg)
        self.height = height
        #: The table's normal (up, toward the camera's side) in the camera frame.
        self.up = np.array([0.0, -math.cos(pitch), -math.sin(pitch)])
        u, v = np.meshgrid(np.arange(self.INTR.width), np.arange(self.INTR.height))
        x = (u - self.INTR.ppx) / self.INTR.fx
        y = (v - self.INTR.ppy) / self.INTR.fy
        self.rays = np.stack([x, y, np.ones(u.shape)], axis=-1)  # points at depth 1 m
        self.along = self.rays @ self.up

    def table_point(self, u: float, v: float) -> np.ndarray:
        """The table's point (camera frame) seen at pixel (u, v)."""
        ray = np.array([(u - self.INTR.ppx) / self.INTR.fx, (v - self.INTR.ppy) / self.INTR.fy, 1])
        return ray * (-self.height / float(ray @ self.up))

    def table_depth(self) -> np.ndarray:
        """Depth (m) of the table alone, 0 where the ray misses it."""
        with np.errstate(divide="ignore"):
            return np.where(self.along < -1e-3, -self.height / self.along, 0.0)

    def heights(self, t: np.ndarray) -> np.ndarray:
        """Height above the table of each pixel's ray at depth ``t``."""
        return t * self.along + self.height

    def cylinder(self, foot: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """Depths where each pixel's ray enters and leaves the infinite vertical cylinder of
        ``radius`` standing at ``foot`` (NaN where it misses): the roots of |t r_o - F_o|^2 =
        R^2, r_o and F_o being the ray's and the foot's parts off the axis."""
        r_o = self.rays - self.along[..., None] * self.up
        f_o = foot - (foot @ self.up) * self.up
        a = np.einsum("...i,...i", r_o, r_o)
        b = r_o @ f_o
        disc = b**2 - a * (f_o @ f_o - radius**2)
        root = np.sqrt(np.where(disc > 0.0, disc, np.nan))
        return (b - root) / a, (b + root) / a

    def vessel(self, foot: np.ndarray, radius: float, height: float, lid: bool) -> np.ndarray:
        """Depth image of the table and a thin-walled vertical cylinder on it: closed by a
        lid at ``height`` (a can) or open (a cup: over its near rim the rays meet its inner
        far wall, or its floor)."""
        depth = self.table_depth()
        near, far = self.cylinder(foot, radius)
        h_near, h_far = self.heights(near), self.heights(far)
        wall = (h_near >= 0.0) & (h_near <= height)
        above = h_near > height  # the ray passes over the rim (or lid)
        if lid:
            with np.errstate(divide="ignore", invalid="ignore"):
                t_lid = (height - self.height) / self.along
            on_lid = above & (self.heights(far) < height) & (t_lid > 0)
            depth = np.where(on_lid, t_lid, depth)
        else:
            inner = above & (h_far >= 0.0) & (h_far <= height)
            depth = np.where(inner, far, depth)
        return np.where(wall, near, depth)

    def capped_box(
        self,
        foot: np.ndarray,
        size: tuple[float, float, float],
        cap: tuple[float, float],
        turn: float = 0.0,
    ) -> np.ndarray:
        """Depth image of the table and an upright box standing at ``foot``, ``size`` (width,
        depth, height; its front faces the camera turned by ``turn`` rad about the vertical),
        with a cylinder of ``cap`` (radius, top height; radius 0 for none) on its top's
        centre: a flat-sided bottle. Each ray's nearest hit of the box's four sides, its top
        and the cap's wall and top."""
        width, depth_, height = size
        cap_radius, cap_top = cap
        toward = -(foot - (foot @ self.up) * self.up)
        toward /= np.linalg.norm(toward)
        side = np.cross(self.up, toward)
        front = math.cos(turn) * toward + math.sin(turn) * side
        lateral = np.cross(self.up, front)
        best = np.full(self.rays.shape[:2], np.inf)

        def hit(t: np.ndarray, on: np.ndarray) -> None:
            on = on & np.isfinite(t) & (t > 0.0) & (t < best)
            best[on] = t[on]

        def at(t: np.ndarray) -> np.ndarray:
            return self.rays * t[..., None] - foot  # the ray's point, from the foot

        with np.errstate(divide="ignore", invalid="ignore"):
            faces = ((front, depth_, lateral, width), (lateral, width, front, depth_))
            for normal, across, along, extent in faces:
                for sign in (1.0, -1.0):
                    t = (0.5 * across + foot @ (sign * normal)) / (self.rays @ (sign * normal))
                    p = at(t)
                    h = p @ self.up
                    hit(t, (np.abs(p @ along) <= 0.5 * extent) & (h >= 0.0) & (h <= height))
            t_lid = (height - self.height) / self.along
            lid = at(t_lid)
            hit(
                t_lid,
                (np.abs(lid @ front) <= 0.5 * depth_) & (np.abs(lid @ lateral) <= 0.5 * width),
            )
            if cap_radius > 0.0:
                near, _ = self.cylinder(foot, cap_radius)
                h_near = self.heights(near)
                hit(near, (h_near >= height) & (h_near <= cap_top))
                t_top = (cap_top - self.height) / self.along
                top = at(t_top)
                off_axis = top - (top @ self.up)[..., None] * self.up
                hit(t_top, np.linalg.norm(off_axis, axis=-1) <= cap_radius)
        return np.where(np.isfinite(best), best, self.table_depth())

    def frame(self, depth: np.ndarray) -> RGBDFrame:
        color = np.full((self.INTR.height, self.INTR.width, 3), 128, np.uint8)
        return RGBDFrame(
            color=color,
            depth=depth.astype(np.float32),
            intrinsics=self.INTR,
            timestamp=0.0,
            index=0,
        )
