"""The simulated workspace: MuJoCo scene, physics clock and ground truth (see world.py).

Offscreen rendering needs OpenGL; with no display we default to EGL (``MUJOCO_GL=egl``), which
Mesa's software renderer provides when there is no GPU (see ``_mujoco.py``).
"""

from __future__ import annotations

from armvision.sim.world import (
    GroundTruth,
    ObjectSpec,
    ObjectState,
    SceneSpec,
    SimWorld,
    generate_scene,
)

__all__ = ["GroundTruth", "ObjectSpec", "ObjectState", "SceneSpec", "SimWorld", "generate_scene"]
