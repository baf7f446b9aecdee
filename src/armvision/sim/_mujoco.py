"""MuJoCo, imported with a headless OpenGL default and a clear error when OpenGL is broken.

MuJoCo picks its OpenGL backend from ``MUJOCO_GL`` when it is first imported, and fails at
import time if that backend cannot load. With no display we default to EGL, which Mesa's
software renderer provides when there is no GPU. Import ``mujoco`` from here.
"""

from __future__ import annotations

import os

from armvision.errors import SimulationError

os.environ.setdefault("MUJOCO_GL", "egl")

GL_HELP = (
    "set MUJOCO_GL=egl (install libegl1 libgl1-mesa-dri; Mesa renders in software with no GPU)"
    " or MUJOCO_GL=osmesa (install libosmesa6) before starting Python"
)

try:
    import mujoco
except Exception as exc:  # RuntimeError, ImportError or AttributeError, depending on backend
    raise SimulationError(
        f"MuJoCo cannot load its OpenGL backend MUJOCO_GL={os.environ.get('MUJOCO_GL')}"
        f" ({type(exc).__name__}: {exc}); {GL_HELP}"
    ) from exc

__all__ = ["GL_HELP", "mujoco"]
