"""Cameras: the RGB-D frame types, the Camera interface, and its backends.

``SimCamera`` lives in ``armvision.sim.camera`` and is imported from there, so that importing
this package does not load MuJoCo.
"""

from __future__ import annotations

from armvision.camera.base import Camera
from armvision.camera.frames import Intrinsics, RGBDFrame, deproject, deproject_image, project

__all__ = ["Camera", "Intrinsics", "RGBDFrame", "deproject", "deproject_image", "project"]
