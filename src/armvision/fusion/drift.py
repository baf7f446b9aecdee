"""Has the camera moved since it was calibrated? The gripper tag as seen against the encoders.

Whenever the gripper tag is in view, the calibration predicts where the camera should see it
(``T_base_cam @ T_cam_tag``) and the encoders say where it is (``fk(q) @ T_ee_tag``, with
``q`` the reading at the frame's capture time). With a good calibration the two agree to a
few millimetres and a fraction of a degree; a knocked camera stand shows as a disagreement
that does not go away. :class:`DriftMonitor` keeps the disagreements of the last
``calibration.drift_window_s`` (position difference in the base frame, and the rotation
between the two tag orientations), takes their per-axis median (robust to a bad detection),
and marks the calibration drifted once that median has exceeded ``drift_mm`` or
``drift_deg`` for ``drift_persist_s``; the mark clears the same way (the camera put back).
Small disagreements stay below the thresholds and are left to the fusion filter's estimate of
the calibration error.

The tag's orientation as detected carries a bias of its own (print, lighting, the pose
estimate's ambiguity) and a calibration fitted to tag positions keeps a rotation error of a
few tenths of a degree, which shows as a constant rotation disagreement at every pose. Both
were there when the calibration was made: :func:`rotation_reference` takes the median
rotation disagreement over the calibration's own samples, and the monitor measures rotation
against it, so what it reports is the change since calibration. A calibration without samples
(a bare transform, the simulator's truth) has no such reference: the first window of
sightings after start sets it, so only the position then catches a camera turned before the
start.

Samples taken while the end effector moves fast are skipped: a few milliseconds' error in a
frame's timestamp would then look like a disagreement.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from armvision.config import CalibrationConfig
from armvision.robot.kinematics import VX300S, ArmModel, fk

_DEFAULTS = CalibrationConfig()

#: End-effector speed above which a sample is not used, m/s.
MAX_SPEED_MPS = 0.05


@dataclass(frozen=True)
class DriftStatus:
    """The camera against the encoders, as of ``checked_at`` (clock seconds).

    ``translation_mm`` and ``rotation_deg``: the median disagreement over the window (None
    until ``samples`` reaches the minimum); ``drifted``: it has exceeded the thresholds
    (``threshold_mm``, ``threshold_deg``) for the persistence time, since ``since``.
    """

    drifted: bool = False
    translation_mm: float | None = None
    rotation_deg: float | None = None
    samples: int = 0
    since: float | None = None
    checked_at: float | None = None
    threshold_mm: float = _DEFAULTS.drift_mm
    threshold_deg: float = _DEFAULTS.drift_deg

    @property
    def measured(self) -> bool:
        return self.translation_mm is not None

    def describe(self) -> str:
        """How far the camera has moved, in words."""
        return f"{self.translation_mm or 0.0:.0f} mm and {self.rotation_deg or 0.0:.1f} deg"

    def refusal(self) -> str | None:
        """The sentence a task that aims from the camera refuses with, or None if fine."""
        if not self.drifted:
            return None
        return (
            f"the camera has moved since calibration (the gripper tag is seen {self.describe()}"
            " from where the encoders put it): recalibrate (Calibrate), or put the camera back"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "drifted": self.drifted,
            "translation_mm": None
            if self.translation_mm is None
            else round(self.translation_mm, 2),
            "rotation_deg": None if self.rotation_deg is None else round(self.rotation_deg, 3),
            "samples": self.samples,
            "since": self.since,
            "checked_at": self.checked_at,
            "threshold_mm": self.threshold_mm,
            "threshold_deg": self.threshold_deg,
        }


#: The tag's orientation counts only from sightings within this angle of facing the camera:
#: seen more obliquely, a tag's measured orientation is off by degrees (its position is not).
MAX_VIEW_ANGLE_DEG = 40.0


def facing(T_cam_tag: ArrayLike) -> bool:
    """Does the tag face the camera within :data:`MAX_VIEW_ANGLE_DEG`?"""
    T = np.asarray(T_cam_tag, dtype=float)
    ray = T[:3, 3] / max(float(np.linalg.norm(T[:3, 3])), 1e-9)
    return abs(float(T[:3, 2] @ ray)) >= math.cos(math.radians(MAX_VIEW_ANGLE_DEG))


def _disagreement(
    T_base_cam: np.ndarray, T_ee_tag: np.ndarray, q: ArrayLike, T_cam_tag: ArrayLike, model
) -> tuple[np.ndarray, np.ndarray]:
    T_seen = T_base_cam @ np.asarray(T_cam_tag, dtype=float)
    T_expected = fk(np.asarray(q, dtype=float), model) @ T_ee_tag
    return T_seen[:3, 3] - T_expected[:3, 3], T_seen[:3, :3] @ T_expected[:3, :3].T


def rotation_reference(
    T_base_cam: ArrayLike,
    T_ee_tag: ArrayLike,
    samples: list[tuple[ArrayLike, ArrayLike]],
    model: ArmModel = VX300S,
) -> np.ndarray | None:
    """The median tag-orientation disagreement (rotation vector, rad) over a calibration's
    samples, each (joint reading as the runtime corrects it, ``T_cam_tag``); None if none."""
    T_base_cam = np.asarray(T_base_cam, dtype=float)
    T_ee_tag = np.asarray(T_ee_tag, dtype=float)
    vectors = [
        Rotation.from_matrix(_disagreement(T_base_cam, T_ee_tag, q, T, model)[1]).as_rotvec()
        for q, T in samples
        if facing(T)
    ]
    if not vectors:
        return None
    reference = np.median(np.array(vectors), axis=0)
    return reference if np.all(np.isfinite(reference)) else None


class DriftMonitor:
    """Watches one calibration (``T_base_cam``, the tag mount ``T_ee_tag``) for drift; feed it
    :meth:`observe`, read :attr:`status`. Not thread-safe: one producer (the fusion loop).
    ``rotation_reference``: see :func:`rotation_reference`; ``active`` False: it only
    reports that nothing was checked (a camera that was never calibrated cannot drift)."""

    def __init__(
        self,
        config: CalibrationConfig,
        T_base_cam: ArrayLike,
        T_ee_tag: ArrayLike,
        rotation_reference: ArrayLike | None = None,
        model: ArmModel = VX300S,
        active: bool = True,
    ) -> None:
        self.config = config
        self.active = active
        self.T_base_cam = np.array(T_base_cam, dtype=float)
        self.T_ee_tag = np.array(T_ee_tag, dtype=float)
        # None: learnt from the first window of sightings (a bare transform has no samples).
        self.R_reference: np.ndarray | None = (
            None
            if rotation_reference is None
            else Rotation.from_rotvec(np.asarray(rotation_reference, dtype=float)).as_matrix()
        )
        self.model = model
        self._window: deque[tuple[float, np.ndarray, np.ndarray | None]] = deque()
        self._over_since: float | None = None  # exceeding since (while not drifted)
        self._under_since: float | None = None  # back within since (while drifted)
        self.status = DriftStatus(threshold_mm=config.drift_mm, threshold_deg=config.drift_deg)

    def observe(
        self, t: float, q: ArrayLike, T_cam_tag: ArrayLike, speed_mps: float = 0.0
    ) -> DriftStatus:
        """One gripper-tag detection at capture time ``t`` with the joint reading ``q`` of that
        instant; ``speed_mps``: the end effector's speed then (fast samples are skipped)."""
        if not self.active or not speed_mps <= MAX_SPEED_MPS or not math.isfinite(t):
            return self.status
        dp, R = _disagreement(self.T_base_cam, self.T_ee_tag, q, T_cam_tag, self.model)
        # Raw (the reference is applied to the window's median), and only from a face-on tag.
        dr = Rotation.from_matrix(R).as_rotvec() if facing(T_cam_tag) else None
        if not (np.all(np.isfinite(dp)) and (dr is None or np.all(np.isfinite(dr)))):
            return self.status
        cfg = self.config
        window = self._window
        window.append((t, dp, dr))
        while window and window[0][0] < t - cfg.drift_window_s:
            window.popleft()
        n = len(window)
        if n < cfg.drift_min_samples:
            self.status = replace(self.status, samples=n, checked_at=t)
            return self.status
        translation_mm = 1000.0 * float(np.linalg.norm(np.median([w[1] for w in window], axis=0)))
        rotations = [w[2] for w in window if w[2] is not None]
        rotation_deg = None
        if len(rotations) >= cfg.drift_min_samples:
            R_median = Rotation.from_rotvec(np.median(rotations, axis=0)).as_matrix()
            if self.R_reference is None:
                self.R_reference = R_median
            rotation = Rotation.from_matrix(R_median @ self.R_reference.T).as_rotvec()
            rotation_deg = math.degrees(float(np.linalg.norm(rotation)))
        over = translation_mm > cfg.drift_mm or (
            rotation_deg is not None and rotation_deg > cfg.drift_deg
        )
        drifted, since = self.status.drifted, self.status.since
        if not drifted:
            self._under_since = None
            if over:
                self._over_since = t if self._over_since is None else self._over_since
                if t - self._over_since >= cfg.drift_persist_s:
                    drifted, since = True, self._over_since
            else:
                self._over_since = None
        else:
            self._over_since = None
            if not over:
                self._under_since = t if self._under_since is None else self._under_since
                if t - self._under_since >= cfg.drift_persist_s:
                    drifted, since = False, None
            else:
                self._under_since = None
        self.status = DriftStatus(
            drifted=drifted,
            translation_mm=translation_mm,
            rotation_deg=rotation_deg,
            samples=n,
            since=since,
            checked_at=t,
            threshold_mm=cfg.drift_mm,
            threshold_deg=cfg.drift_deg,
        )
        return self.status
