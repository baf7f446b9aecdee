"""The simulated workspace: scene generation (scene.py), the MuJoCo model (model.py, with the
robot in data/vx300s.xml), physics clock and ground truth (world.py).

Offscreen rendering needs OpenGL; with no display we default to EGL (``MUJOCO_GL=egl``), which
Mesa's software renderer provides when there is no GPU (see ``_mujoco.py``).
"""

from __future__ import annotations

from armvision.sim.scene import ObjectSpec, SceneSpec, generate_scene
from armvision.sim.world import GroundTruth, ObjectState, SimWorld

__all__ = ["GroundTruth", "ObjectSpec", "ObjectState", "SceneSpec", "SimWorld", "generate_scene"]
