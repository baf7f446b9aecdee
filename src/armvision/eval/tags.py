"""Gripper-tag pose accuracy in simulation, with and without depth refinement.

For each seed the camera is placed at random (``sim.randomize_camera``) and the arm shows the
tag at several poses: the tag centre 0.5-1.2 m from the camera somewhere in its view, the tag
face turned toward the camera within ``max_tilt_deg``. The truth is the simulator's
``T_base_cam^-1 T_base_tag``; the detector sees only the rendered, noisy RGB-D frame.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from armvision.config import Config
from armvision.geometry import inv_T, make_T, pose_error, rotation_between
from armvision.perception.tags import TagDetector
from armvision.robot.kinematics import ik


def _tag_pose_facing_camera(
    rng: np.random.Generator, T_base_cam: np.ndarray, distance: float, max_tilt_deg: float
) -> np.ndarray:
    """``T_base_tag`` at ``distance`` inside the view, its face turned to the camera +- tilt."""
    # A direction within the central part of the D435's 69 x 42 degree view.
    direction_cam = np.array(
        [
            math.tan(math.radians(rng.uniform(-22, 22))),
            math.tan(math.radians(rng.uniform(-13, 13))),
            1.0,
        ]
    )
    direction_cam /= np.linalg.norm(direction_cam)
    p_base = T_base_cam[:3, :3] @ (direction_cam * distance) + T_base_cam[:3, 3]
    # The tag's z axis points into the tag: along the viewing ray when it faces the camera.
    z_base = T_base_cam[:3, :3] @ direction_cam
    tilt_axis = np.cross(z_base, rng.normal(size=3))
    tilt_axis /= np.linalg.norm(tilt_axis)
    tilt = math.radians(rng.uniform(0.0, max_tilt_deg))
    z_tilted = z_base * math.cos(tilt) + np.cross(tilt_axis, z_base) * math.sin(tilt)
    R_base_tag = rotation_between([0.0, 0.0, 1.0], z_tilted)
    spin = rng.uniform(-math.pi, math.pi)  # any rotation of the tag about its own normal
    c, s = math.cos(spin), math.sin(spin)
    R_base_tag = R_base_tag @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return make_T(R_base_tag, p_base)


def evaluate_tags(
    config: Config,
    seeds: list[int],
    poses_per_seed: int = 4,
    distance_range: tuple[float, float] = (0.5, 1.2),
    max_tilt_deg: float = 40.0,
) -> dict[str, Any]:
    """Tag pose errors over ``seeds`` x ``poses_per_seed`` views; see the module docstring."""
    from armvision.sim.arm import SimArm
    from armvision.sim.camera import SimCamera
    from armvision.sim.world import SimWorld

    config = dataclasses.replace(
        config,
        sim=dataclasses.replace(config.sim, randomize_camera=True, min_objects=0, max_objects=0),
    )
    refined = TagDetector.from_config(config.tag, ids=[config.tag.id])
    plain = TagDetector.from_config(config.tag, ids=[config.tag.id], refine_with_depth=False)
    views: list[dict[str, Any]] = []
    attempts = 0
    for seed in seeds:
        rng = np.random.default_rng([seed, 0x7A6])
        with SimWorld(config, seed) as world, SimCamera(world) as camera:
            arm = SimArm(world)
            T_base_cam = world.T_base_cam()
            shown = 0
            while shown < poses_per_seed and attempts < 40 * len(seeds) * poses_per_seed:
                attempts += 1
                distance = rng.uniform(*distance_range)
                T_base_tag = _tag_pose_facing_camera(rng, T_base_cam, distance, max_tilt_deg)
                if T_base_tag[2, 3] < 0.08:  # the gripper would hit the table
                    continue
                T_base_ee = T_base_tag @ inv_T(world.T_ee_tag)
                # Most random poses are out of reach; ask IK first so the arm doesn't log each.
                q, reachable = ik(T_base_ee, arm.get_joint_positions())
                if not reachable or not arm.set_joint_positions(q, moving_time=3.0):
                    continue
                world.advance(0.3)
                frame = camera.read()
                T_cam_tag_true = inv_T(world.T_base_cam()) @ world.T_base_tag()
                view: dict[str, Any] = {
                    "seed": seed,
                    "distance_m": float(np.linalg.norm(T_cam_tag_true[:3, 3])),
                }
                for name, detector in (("depth", refined), ("pnp", plain)):
                    found = detector.detect(frame)
                    if found:
                        dp, dr = pose_error(found[0].T_cam_tag, T_cam_tag_true)
                        view[f"position_error_mm_{name}"] = 1000.0 * float(dp)
                        view[f"rotation_error_deg_{name}"] = math.degrees(float(dr))
                    else:
                        view[f"position_error_mm_{name}"] = None
                        view[f"rotation_error_deg_{name}"] = None
                views.append(view)
                shown += 1

    def stat(key: str, fn) -> float | None:
        values = [v[key] for v in views if v[key] is not None]
        return float(fn(values)) if values else None

    detected = [v for v in views if v["position_error_mm_depth"] is not None]
    summary = {
        "tag_position_error_mm_median": stat("position_error_mm_depth", np.median),
        "tag_rotation_error_deg_median": stat("rotation_error_deg_depth", np.median),
        "tag_position_error_mm_p95": stat(
            "position_error_mm_depth", lambda x: np.percentile(x, 95)
        ),
        "tag_rotation_error_deg_p95": stat(
            "rotation_error_deg_depth", lambda x: np.percentile(x, 95)
        ),
        "tag_position_error_mm_median_no_depth": stat("position_error_mm_pnp", np.median),
        "tag_rotation_error_deg_median_no_depth": stat("rotation_error_deg_pnp", np.median),
        "tag_rotation_error_deg_p95_no_depth": stat(
            "rotation_error_deg_pnp", lambda x: np.percentile(x, 95)
        ),
        "tag_views": len(views),
        "tag_detection_rate": len(detected) / len(views) if views else 0.0,
    }
    return {"summary": summary, "views": views}
