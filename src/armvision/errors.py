"""Errors a user can cause. Every message says what to do about it."""

from __future__ import annotations


class ArmvisionError(Exception):
    """Base of every error armvision raises on purpose; the CLI prints its message, no traceback."""


class ConfigError(ArmvisionError):
    """A configuration file or override is unreadable, has an unknown key or a bad value."""


class HardwareError(ArmvisionError):
    """A device (camera, arm) or its driver stack is missing, unplugged or misbehaving."""


class SimulationError(ArmvisionError):
    """The simulated workspace cannot be built or rendered (for example no OpenGL for MUJOCO_GL)."""


class CalibrationError(ArmvisionError):
    """Camera-to-robot calibration failed, or a saved calibration file is unusable."""


class PerceptionError(ArmvisionError):
    """A detector cannot run (missing model file, bad input image)."""
