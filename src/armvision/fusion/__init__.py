"""Fusion of camera and joint encoders, and tracking of bottles and cups.

- :mod:`armvision.fusion.kalman`: the paper's 7-state filter (:class:`PaperKF`, for reference)
  and the default end-effector filter (:class:`EEFilter`) with its building blocks.
- :mod:`armvision.fusion.tracker`: many objects at once (:class:`MultiObjectTracker`).
- :mod:`armvision.fusion.loop`: the 100 Hz fusion thread (:class:`FusionLoop`) that publishes
  immutable snapshots for the runtime.
"""

from __future__ import annotations

from armvision.errors import ArmvisionError


class FusionError(ArmvisionError):
    """Bad input to a filter or tracker (wrong shape, non-finite values, time going backwards)."""


__all__ = ["FusionError"]
