"""Shared simulated worlds and cameras, built once per session (building and GL set-up cost).

Tests that change a shared world (camera pose, marker, arm) set what they need first and do
not rely on what other tests left behind.
"""

from __future__ import annotations

import pytest
from tests.sim.helpers import config_with

from armvision.sim.camera import SimCamera
from armvision.sim.world import SimWorld


@pytest.fixture(scope="session")
def empty_world() -> SimWorld:
    """The workspace without objects: nothing for the arm to bump into."""
    return SimWorld(config_with(min_objects=0, max_objects=0), seed=11)


@pytest.fixture(scope="session")
def camera(empty_world: SimWorld) -> SimCamera:
    """The D435i of the empty world, started (tests move it with ``set_camera_pose``)."""
    cam = SimCamera(empty_world)
    cam.start()
    yield cam
    cam.stop()
