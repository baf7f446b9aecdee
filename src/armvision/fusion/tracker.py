"""Multi-object tracking of bottles and cups in the base frame.

One :class:`~armvision.fusion.kalman.MotionFilter` per object (constant velocity, the adaptive
process noise of the end-effector filter, so a bottle picked up and carried is followed and a
bottle standing still is averaged). Per camera frame:

1. every track is predicted to the frame's time;
2. detections are associated to tracks by the Hungarian method
   (:func:`scipy.optimize.linear_sum_assignment`) on the squared Mahalanobis distance
   d^2 = y^T S^-1 y, S = H P H^T + R, plus ``label_mismatch_cost`` when the labels differ;
   pairs beyond the chi-square gate (``gate_probability``, 3 degrees of freedom) are never
   associated (global nearest neighbour, Bar-Shalom et al. 2001, section 3.7; Blackman &
   Popoli, "Design and Analysis of Modern Tracking Systems", 1999, section 6.4); what is
   left is matched once more by distance alone within ``reassociation_radius`` (an object
   that stopped abruptly is gated out by its own prediction, see ``_reassociate``);
3. associated tracks are updated; a detection left over starts a tentative track. A
   detection whose fitted radius is dr off its track's (beyond the fit's scatter) counts with
   dr^2 more variance per axis, in the association and the update (``SIZE_KNOWN_AFTER``);
4. a tentative track is confirmed once it has ``confirm_hits`` hits in its last
   ``confirm_window`` frames (M of N), and dropped when it can no longer get there; any track
   unseen for ``drop_after_s`` seconds is dropped.

Tracks keep their id for life (ids count up from 1 and are never reused) and their label is the
score-weighted vote of every detection associated with them. Measurements come from
:func:`measurement_from_detection`: the detector's centre in the camera frame, mapped to the
base frame by the calibration, with the camera's noise model as covariance.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from armvision.config import FusionConfig
from armvision.fusion import FusionError
from armvision.fusion.kalman import (
    DEFAULT_FOCAL_PX,
    Measurement,
    MotionFilter,
    as_array,
    as_time,
    camera_point_covariance,
    gate_threshold,
)

Array = NDArray[np.float64]

#: Added to d^2 when a detection's label differs from the track's: a bottle detection prefers a
#: bottle track of similar distance, but a label error never blocks an association.
LABEL_MISMATCH_COST = 4.0
#: Initial velocity spread of a new track, m/s: objects are usually still when first seen.
NEW_TRACK_SPEED_SIGMA = 0.2
#: While a track is not seen, its velocity decays with this time constant, s: an object that
#: leaves the detections (hidden by the arm, lifted off the table in the gripper, or seen last
#: as a sliver whose fits walked) is far likelier to stand where it was than to go on at its
#: last velocity, and a track that coasts on for ``drop_after_s`` at the velocity of a few
#: partial fits slides centimetres away from the object (16 mm/s over a second, a bottle
#: closed on by the fingers in the demo's grab). A moving object seen again within a frame or
#: two keeps most of its velocity, and the reassociation radius catches it otherwise.
COAST_TIME_S = 0.2
#: Size (radius, height) of a track: the median of its last this many detections.
SIZE_WINDOW = 15
#: A track's radius counts against a detection's once it has this many radii: a detection
#: whose fitted radius is off the track's by more than the fit's own scatter
#: (``SIZE_TOLERANCE_M``) by dr has a centre about dr off too (a partly hidden object's
#: visible arc fitted with a third of its radius, or a circle across two objects), so dr^2 is
#: added to its covariance on each axis. Within the scatter nothing changes: a weight that
#: followed every millimetre of radius would make the track depend on pixel noise.
SIZE_KNOWN_AFTER = 5
SIZE_TOLERANCE_M = 0.005
_H = np.hstack([np.eye(3), np.zeros((3, 3))])


@dataclass(frozen=True, eq=False)
class ObjectMeasurement:
    """A detected object's centre in the base frame: ``p_base`` (3,), covariance ``R_base``
    (3, 3), ``label`` ("bottle", "cup") and detector ``score`` in [0, 1]. ``radius`` and
    ``height`` (m) and the image ``box`` (x0, y0, x1, y1) when the detector gives them."""

    p_base: Array
    R_base: Array
    label: str
    score: float = 1.0
    radius: float | None = None
    height: float | None = None
    box: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "p_base", as_array("p_base", self.p_base, (3,)))
        R = as_array("R_base", self.R_base, (3, 3))
        if not np.allclose(R, R.T, atol=1e-12) or np.any(np.linalg.eigvalsh(R) <= 0.0):
            raise FusionError("R_base must be a symmetric positive definite covariance")
        object.__setattr__(self, "R_base", R)
        score = float(self.score)
        if not (math.isfinite(score) and 0.0 <= score <= 1.0):
            raise FusionError(f"score must be in [0, 1], got {self.score}")
        object.__setattr__(self, "score", score)


class DetectionLike(Protocol):
    """What :func:`measurement_from_detection` reads of a detection: perception's
    ``Detection`` has it all; ``radius``, ``height`` and ``box`` are read when present."""

    @property
    def label(self) -> str: ...
    @property
    def score(self) -> float: ...
    @property
    def center_cam(self) -> ArrayLike: ...


def measurement_from_detection(
    detection: DetectionLike,
    T_base_cam: ArrayLike,
    config: FusionConfig,
    focal_px: float = DEFAULT_FOCAL_PX,
) -> ObjectMeasurement:
    """An :class:`ObjectMeasurement` from a perception ``Detection`` (camera frame).

    p_base = T_base_cam p_cam; R = R_base_cam Sigma R_base_cam^T with Sigma from
    :func:`~armvision.fusion.kalman.camera_point_covariance` (the pixel noise across the ray,
    Intel's depth RMS along it) and at least ``config.object_sigma_floor`` per axis for the
    detector's own error (the fitted circle, the height estimate).
    """
    T_base_cam = as_array("T_base_cam", T_base_cam, (4, 4))
    p_cam = as_array("detection.center_cam", detection.center_cam, (3,))
    cov_cam = (
        camera_point_covariance(
            p_cam, config.camera_pixel_sigma, focal_px, config.camera_depth_scale
        )
        + np.eye(3) * config.object_sigma_floor**2
    )
    R_base_cam = T_base_cam[:3, :3]
    box = getattr(detection, "box", None)
    return ObjectMeasurement(
        p_base=R_base_cam @ p_cam + T_base_cam[:3, 3],
        R_base=R_base_cam @ cov_cam @ R_base_cam.T,
        label=str(detection.label),
        score=float(np.clip(detection.score, 0.0, 1.0)),
        radius=_finite_or_none(getattr(detection, "radius", None)),
        height=_finite_or_none(getattr(detection, "height", None)),
        box=None if box is None else _box(box),
    )


def _box(box: Iterable[float]) -> tuple[float, float, float, float]:
    values = [float(v) for v in box]
    if len(values) != 4:
        raise FusionError(f"detection.box must be (x0, y0, x1, y1), got {box!r}")
    x0, y0, x1, y1 = values
    return x0, y0, x1, y1


def _finite_or_none(value: float | None) -> float | None:
    """``value`` as a positive finite float, else None (also for what float() cannot take)."""
    if value is None:
        return None
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) and v > 0.0 else None


@dataclass(frozen=True, eq=False)
class TrackState:
    """One track at time ``t``: base-frame position, velocity, their 6x6 covariance ``cov``.

    ``votes`` maps each label to its summed detection score; ``label`` is the winner.
    ``hits`` counts associated detections, ``last_seen`` is the newest one's time. Arrays are
    read-only.
    """

    id: int
    label: str
    confirmed: bool
    t: float
    p_base: Array
    v_base: Array
    cov: Array
    hits: int
    last_seen: float
    votes: tuple[tuple[str, float], ...]
    radius: float | None = None
    height: float | None = None
    box: tuple[float, float, float, float] | None = None

    @property
    def sigma_mm(self) -> float:
        """RMS positional standard deviation, sqrt(trace(P_pp)), millimetres."""
        return 1000.0 * math.sqrt(max(float(np.trace(self.cov[:3, :3])), 0.0))


class _Track:
    def __init__(self, track_id: int, t: float, m: ObjectMeasurement, config: FusionConfig):
        self.id = track_id
        self.filter = MotionFilter(
            order=2,
            noise_density=config.object_accel_noise,
            gate_probability=None,  # the association gates
            adaptive=config.adaptive_noise,
            adaptive_fading=config.adaptive_fading,
            adaptive_threshold=config.adaptive_threshold,
            adaptive_max_scale=config.adaptive_max_scale,
        )
        P0 = np.zeros((6, 6))
        P0[:3, :3] = m.R_base
        P0[3:, 3:] = np.eye(3) * NEW_TRACK_SPEED_SIGMA**2
        self.filter.initialize(t, np.concatenate([m.p_base, np.zeros(3)]), P0)
        self.history: deque[bool] = deque([True], maxlen=config.confirm_window)
        self.confirmed = config.confirm_hits <= 1
        self.hits = 1
        self.last_seen = t
        self.votes: dict[str, float] = {m.label: max(m.score, 1e-6)}
        self.radii: deque[float] = deque(maxlen=SIZE_WINDOW)
        self.heights: deque[float] = deque(maxlen=SIZE_WINDOW)
        self.box: tuple[float, float, float, float] | None = None
        #: Medians of ``radii`` and ``heights``, kept with them: the fusion thread reads them
        #: every cycle (statistics.median: a fraction of np.median's cost on 15 numbers).
        self.radius: float | None = None
        self.height: float | None = None
        self.add_size(m)

    def add_size(self, m: ObjectMeasurement) -> None:
        if m.radius is not None:
            self.radii.append(m.radius)
            self.radius = float(statistics.median(self.radii))
        if m.height is not None:
            self.heights.append(m.height)
            self.height = float(statistics.median(self.heights))
        self.box = m.box

    def coast(self, dt: float) -> None:
        """Decay the velocity over ``dt`` unseen seconds (see ``COAST_TIME_S``): the linear map
        v <- a v with a = exp(-dt / COAST_TIME_S), applied to the mean and the covariance."""
        f = self.filter
        a = math.exp(-max(dt, 0.0) / COAST_TIME_S)
        f.x[3:6] *= a
        f.P[3:6, :] *= a
        f.P[:, 3:6] *= a

    @property
    def label(self) -> str:
        return max(sorted(self.votes), key=lambda k: self.votes[k])

    def size_variance(self, m: ObjectMeasurement) -> float:
        """dr^2, dr how far the detection's radius is off the track's beyond
        ``SIZE_TOLERANCE_M`` (0 while either is unknown)."""
        if m.radius is None or len(self.radii) < SIZE_KNOWN_AFTER:
            return 0.0
        assert self.radius is not None  # set with radii
        return max(abs(m.radius - self.radius) - SIZE_TOLERANCE_M, 0.0) ** 2

    def state(self, t: float | None = None) -> TrackState:
        f = self.filter
        assert f.t is not None  # initialised in __init__
        t_state = f.t if t is None else max(t, f.t)
        x, P = f.predicted(t_state)
        p, v, cov = x[:3].copy(), x[3:6].copy(), P.copy()
        for a in (p, v, cov):
            a.flags.writeable = False
        return TrackState(
            id=self.id,
            label=self.label,
            confirmed=self.confirmed,
            t=float(t_state),
            p_base=p,
            v_base=v,
            cov=cov,
            hits=self.hits,
            last_seen=self.last_seen,
            votes=tuple(sorted(self.votes.items())),
            radius=self.radius,
            height=self.height,
            box=self.box,
        )


class MultiObjectTracker:
    """Tracks of bottles and cups from per-frame detections (see the module docstring).

    ``config``: the ``fusion`` section (M of N, drop time, gate, noise). Call :meth:`update`
    once per processed camera frame, with every detection of that frame (an empty list when
    nothing was seen, so misses count), in time order.
    """

    def __init__(self, config: FusionConfig | None = None) -> None:
        self.config = config if config is not None else FusionConfig()
        self._tracks: list[_Track] = []
        self._next_id = 1
        self.t: float | None = None
        self.frames = 0
        self.dropped_frames = 0
        self.reassociated = 0

    @property
    def gate(self) -> float:
        return gate_threshold(self.config.gate_probability, 3)

    def cost_matrix(self, t: float, measurements: Sequence[ObjectMeasurement]) -> Array:
        """d^2 (+ label cost) of every track (rows) against every measurement (columns)."""
        if not self._tracks or not measurements:
            return np.zeros((len(self._tracks), len(measurements)))
        predicted = [track.filter.predicted(t) for track in self._tracks]
        x = np.array([xp[:3] for xp, _ in predicted])  # (T, 3)
        P = np.array([Pp[:3, :3] for _, Pp in predicted])  # (T, 3, 3)
        z = np.array([m.p_base for m in measurements])  # (M, 3)
        R = np.array([m.R_base for m in measurements])  # (M, 3, 3)
        y = z[None, :, :] - x[:, None, :]  # (T, M, 3)
        size = np.array([[track.size_variance(m) for m in measurements] for track in self._tracks])
        S = P[:, None] + R[None, :] + size[..., None, None] * np.eye(3)  # (T, M, 3, 3)
        d2 = np.einsum("tmi,tmi->tm", y, np.linalg.solve(S, y[..., None])[..., 0])
        labels = np.array([track.label for track in self._tracks])
        mismatch = labels[:, None] != np.array([m.label for m in measurements])[None, :]
        return d2 + LABEL_MISMATCH_COST * mismatch

    def update(self, t: float, measurements: Sequence[ObjectMeasurement]) -> list[TrackState]:
        """Fuse one frame's detections taken at time ``t``; the confirmed tracks after it."""
        t = as_time("t", t)
        for m in measurements:
            if not isinstance(m, ObjectMeasurement):
                raise FusionError(
                    f"expected ObjectMeasurement, got {type(m).__name__}: convert detections "
                    "with measurement_from_detection(detection, T_base_cam, config)"
                )
        if self.t is not None and t < self.t:
            self.dropped_frames += 1  # one camera delivers in order; an old frame is stale
            return self.confirmed_tracks()
        # Every track was predicted to (or started at) the last frame's time.
        dt = 0.0 if self.t is None else t - self.t
        self.t = t
        self.frames += 1
        for track in self._tracks:
            track.filter.predict(t)
        assigned: dict[int, int] = {}
        if self._tracks and measurements:
            cost = self.cost_matrix(t, measurements)
            big = 1e6  # linear_sum_assignment needs finite costs; gated pairs are cut below
            rows, cols = linear_sum_assignment(np.where(cost <= self.gate, cost, big))
            assigned = {int(c): int(r) for r, c in zip(rows, cols) if cost[r, c] <= self.gate}
            self._reassociate(t, measurements, assigned)
        seen = set(assigned.values())
        for j, m in enumerate(measurements):
            if j in assigned:
                track = self._tracks[assigned[j]]
                R = m.R_base + np.eye(3) * track.size_variance(m)
                track.filter.update([Measurement("camera", m.p_base, _H, R)], gate=False)
                track.history.append(True)
                track.hits += 1
                track.last_seen = t
                track.votes[m.label] = track.votes.get(m.label, 0.0) + max(m.score, 1e-6)
                track.add_size(m)
            else:
                self._tracks.append(_Track(self._next_id, t, m, self.config))
                self._next_id += 1
                seen.add(len(self._tracks) - 1)
        cfg = self.config
        keep = []
        for i, track in enumerate(self._tracks):
            if i not in seen:
                track.history.append(False)
                track.coast(dt)
            if not track.confirmed and sum(track.history) >= cfg.confirm_hits:
                track.confirmed = True
            hopeless = (
                not track.confirmed
                and sum(track.history) + (cfg.confirm_window - len(track.history))
                < cfg.confirm_hits
            )
            stale = t - track.last_seen > cfg.drop_after_s
            if not (hopeless or stale):
                keep.append(track)
        self._tracks = keep
        return self.confirmed_tracks()

    def _reassociate(
        self, t: float, measurements: Sequence[ObjectMeasurement], assigned: dict[int, int]
    ) -> None:
        """Second stage: leftover detections to leftover tracks by distance alone.

        A track whose object stopped or turned abruptly predicts past it, and its covariance,
        small while the motion was smooth, gates the detection out. Two objects cannot stand
        closer than their diameters, so a detection within ``reassociation_radius`` of a
        track's prediction that no other track took is that track's object (the idea of
        cascaded association, as in DeepSORT and ByteTrack). Updated with it, the track's
        large innovation raises its adaptive process noise.
        """
        free_tracks = [i for i in range(len(self._tracks)) if i not in assigned.values()]
        free_meas = [j for j in range(len(measurements)) if j not in assigned]
        if not free_tracks or not free_meas:
            return
        radius = self.config.reassociation_radius
        dist = np.array(
            [
                [
                    np.linalg.norm(measurements[j].p_base - self._tracks[i].filter.x[:3])
                    for j in free_meas
                ]
                for i in free_tracks
            ]
        )
        rows, cols = linear_sum_assignment(np.where(dist <= radius, dist, 1e6))
        for r, c in zip(rows, cols):
            if dist[r, c] <= radius:
                assigned[free_meas[c]] = free_tracks[r]
                self.reassociated += 1

    def tracks(self, t: float | None = None, include_tentative: bool = False) -> list[TrackState]:
        """Track states (predicted to ``t`` if given), confirmed only unless asked."""
        return [track.state(t) for track in self._tracks if track.confirmed or include_tentative]

    def confirmed_tracks(self) -> list[TrackState]:
        return self.tracks()
