"""Where the camera stands relative to the arm before any calibration: the bench layout.

The configured placement (``sim.camera_*``: distance, bearing, height and pitch, the same
numbers a user measures with a tape on the real bench) gives the nominal ``T_base_cam`` that
the simulated bench mounts its camera at and that an uncalibrated real system shows.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from armvision.config import SimConfig
from armvision.geometry import make_T

Array = NDArray[np.float64]


def camera_pose_from_placement(
    distance: float, azimuth: float, height: float, pitch: float
) -> Array:
    """``T_base_cam`` (OpenCV optical frame) of a camera facing the base axis, pitched down.

    The camera sits ``distance`` from the base z axis at bearing ``azimuth`` (rad, 0 = +x) and
    ``height`` above the base; its optical axis points horizontally at the base axis, then
    tilts down by ``pitch`` (rad). Image x is horizontal (no roll).
    """
    p_base_cam = np.array([distance * math.cos(azimuth), distance * math.sin(azimuth), height])
    forward = -np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
    z_cam = math.cos(pitch) * forward + math.sin(pitch) * np.array([0.0, 0.0, -1.0])
    x_cam = np.cross(z_cam, [0.0, 0.0, 1.0])
    x_cam /= np.linalg.norm(x_cam)
    y_cam = np.cross(z_cam, x_cam)
    return make_T(np.column_stack([x_cam, y_cam, z_cam]), p_base_cam)


def nominal_camera_pose(sim: SimConfig) -> Array:
    """``T_base_cam`` of the configured placement, without the simulation's per-seed jitter."""
    return camera_pose_from_placement(
        sim.camera_distance,
        math.radians(sim.camera_azimuth_deg),
        sim.camera_height,
        math.radians(sim.camera_pitch_deg),
    )
