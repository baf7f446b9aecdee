"""Shared by the detector tests: a scene of placed objects rendered once and detected."""

from __future__ import annotations

import numpy as np

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
