"""Multi-object tracker against known truth.

Measurements here are generated from true object positions plus the camera's noise model
(``camera_point_covariance`` rotated into the base frame, plus the detector floor), not by
rendering: rendering and detecting every frame of these runs would take minutes. The same
tracker on rendered frames through GeometricDetector, with the simulator's truth, is measured
by ``armvision eval fusion`` (and a short run of it in test_eval.py).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from armvision.config import FusionConfig
from armvision.fusion import FusionError
from armvision.fusion.kalman import camera_point_covariance
from armvision.fusion.tracker import (
    MultiObjectTracker,
    ObjectMeasurement,
    measurement_from_detection,
)
from armvision.geometry import make_T, rpy_to_R

T_BASE_CAM = make_T(rpy_to_R(-2.1, 0.0, math.pi / 2), [1.0, 0.0, 0.45])
FPS = 30.0


def noisy(p_base, rng, config=None, label="bottle", score=0.9) -> ObjectMeasurement:
    """A detection of an object centred at ``p_base`` with the camera's noise."""
    config = FusionConfig() if config is None else config
    R_bc = T_BASE_CAM[:3, :3]
    p_cam = R_bc.T @ (np.asarray(p_base) - T_BASE_CAM[:3, 3])
    cov_cam = (
        camera_point_covariance(p_cam, config.camera_pixel_sigma, 615.0, config.camera_depth_scale)
        + np.eye(3) * config.object_sigma_floor**2
    )
    R = R_bc @ cov_cam @ R_bc.T
    return ObjectMeasurement(rng.multivariate_normal(p_base, R), R, label, score)


def rmse(errors) -> float:
    e = np.asarray(errors).reshape(-1, 3)
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


class IdSwitchCounter:
    """CLEAR MOT identity switches: nearest confirmed track within 5 cm of each object."""

    def __init__(self) -> None:
        self.last: dict[int, int] = {}
        self.switches = 0
        self.errors: dict[int, list[np.ndarray]] = {}

    def add(self, truth: np.ndarray, tracks) -> None:
        from scipy.optimize import linear_sum_assignment

        if not tracks:
            return
        dist = np.array([[np.linalg.norm(tr.p_base - p) for tr in tracks] for p in truth])
        for k, j in zip(*linear_sum_assignment(dist)):
            if dist[k, j] > 0.05:
                continue
            if k in self.last and self.last[k] != tracks[j].id:
                self.switches += 1
            self.last[k] = tracks[j].id
            self.errors.setdefault(int(k), []).append(tracks[j].p_base - truth[k])


@pytest.mark.parametrize(
    ("accel_noise", "ratio"),
    [(FusionConfig().object_accel_noise, 0.6), (0.005, 0.35)],  # the default; a still scene
)
def test_static_bottles_are_averaged_below_the_detection_noise(accel_noise, ratio):
    """Three still objects for 3 s: ids 1-3 from the third frame on, no switch, and the track
    error a fraction of a single detection's (smaller with less process noise)."""
    rng = np.random.default_rng(0)
    truth = np.array([[0.35, -0.15, 0.1], [0.45, 0.0, 0.1], [0.35, 0.15, 0.05]])
    tracker = MultiObjectTracker(FusionConfig(object_accel_noise=accel_noise))
    raw, ids = [], []
    counter = IdSwitchCounter()
    for k in range(90):
        meas = [noisy(p, rng) for p in truth]
        raw += [m.p_base - p for m, p in zip(meas, truth)]
        tracks = tracker.update(k / FPS, meas)
        counter.add(truth, tracks)
        ids.append(sorted(t.id for t in tracks))
    assert ids[1] == [] and ids[2] == [1, 2, 3]  # confirmed at the 3rd hit (M = 3)
    assert all(i == [1, 2, 3] for i in ids[2:])
    assert counter.switches == 0
    late = [e for k in counter.errors for e in counter.errors[k][-30:]]
    assert rmse(late) < ratio * rmse(raw)
    # The reported covariance matches the error: sigma per axis within a factor of 2.
    sigma = np.mean([math.sqrt(np.trace(tr.cov[:3, :3]) / 3) for tr in tracker.tracks()])
    assert 0.5 < rmse(late) / math.sqrt(3) / sigma < 2.0


def test_four_objects_on_crossing_paths_keep_their_ids():
    """Two pairs crossing on perpendicular diagonals at 0.1 m/s, each pair passing its
    crossing point 10 cm apart, plus a miss now and then: no identity switch."""
    rng = np.random.default_rng(1)
    starts = np.array([[0.30, -0.22], [0.30, -0.06], [0.30, 0.06], [0.30, 0.22]])
    goals = np.array([starts[1], starts[0], starts[3], starts[2]]) + np.array([0.16, 0.0])
    lag, travel = 1.6, 2.2

    def truth_at(t: float) -> np.ndarray:
        xy = np.empty((4, 2))
        for k in range(4):
            f = np.clip((t - (lag if k % 2 else 0.0)) / travel, 0.0, 1.0)
            xy[k] = starts[k] + f * (goals[k] - starts[k])
        return np.column_stack([xy, np.full(4, 0.1)])

    gaps = [
        min(np.linalg.norm(truth_at(t)[i] - truth_at(t)[j]) for t in np.arange(0, 4, 0.01))
        for i, j in ((0, 1), (2, 3))
    ]
    assert 0.09 < min(gaps) < 0.12  # they do come close
    tracker = MultiObjectTracker()
    counter = IdSwitchCounter()
    for k in range(int(4.5 * FPS)):
        t = k / FPS
        truth = truth_at(t)
        meas = [noisy(p, rng) for i, p in enumerate(truth) if rng.uniform() > 0.1 or k < 5]
        counter.add(truth, tracker.update(t, meas))
    assert counter.switches == 0
    assert len(counter.last) == 4 and len(set(counter.last.values())) == 4
    assert rmse([e for v in counter.errors.values() for e in v]) < 0.005


def test_a_bottle_moved_along_a_curve_is_followed():
    rng = np.random.default_rng(2)
    tracker = MultiObjectTracker()
    errors = []
    for k in range(int(4 * FPS)):
        t = k / FPS
        # Still for 1 s, then a quarter circle of radius 0.15 m in 2 s, then still.
        s = np.clip((t - 1.0) / 2.0, 0.0, 1.0)
        a = 0.5 * math.pi * 0.5 * (1 - math.cos(math.pi * s))
        truth = np.array([0.3 + 0.15 * math.sin(a), -0.1 + 0.15 * (1 - math.cos(a)), 0.1])
        tracks = tracker.update(t, [noisy(truth, rng)])
        if tracks:
            assert [tr.id for tr in tracks] == [1]
            errors.append(tracks[0].p_base - truth)
    assert rmse(errors) < 0.005


def test_m_of_n_confirmation_and_clutter():
    """Seen in frames 0, 2 and 4 (3 of 5): confirmed at frame 4. A one-off clutter detection
    never becomes a confirmed track and is forgotten."""
    rng = np.random.default_rng(3)
    tracker = MultiObjectTracker(FusionConfig(confirm_hits=3, confirm_window=5))
    p = np.array([0.4, 0.0, 0.1])
    confirmed_at = None
    for k in range(8):
        meas = [noisy(p, rng)] if k % 2 == 0 else []
        if k == 1:
            meas.append(noisy([0.3, 0.2, 0.05], rng, label="cup"))  # clutter
        tracks = tracker.update(k / FPS, meas)
        if tracks and confirmed_at is None:
            confirmed_at = k
        assert all(tr.label == "bottle" for tr in tracks)
    assert confirmed_at == 4
    assert len(tracker.tracks(include_tentative=True)) == 1


def test_tracks_are_dropped_after_the_unseen_time_and_ids_are_not_reused():
    rng = np.random.default_rng(4)
    tracker = MultiObjectTracker(FusionConfig(drop_after_s=0.5))
    p = np.array([0.4, 0.1, 0.1])
    for k in range(10):
        tracker.update(k / FPS, [noisy(p, rng)])
    t_last = 9 / FPS
    for k in range(10, 40):
        tracks = tracker.update(k / FPS, [])
        gone = k / FPS - t_last > 0.5
        assert (tracks == []) == gone
    for k in range(40, 45):
        tracks = tracker.update(k / FPS, [noisy(p, rng)])
    assert [tr.id for tr in tracks] == [2]


def test_label_is_the_score_weighted_vote():
    rng = np.random.default_rng(5)
    tracker = MultiObjectTracker()
    p = np.array([0.4, 0.0, 0.05])
    labels = [("cup", 0.9), ("cup", 0.8), ("bottle", 0.3), ("bottle", 0.4), ("cup", 0.2)]
    for k, (label, score) in enumerate(labels):
        tracks = tracker.update(k / FPS, [noisy(p, rng, label=label, score=score)])
    assert tracks[0].label == "cup"
    assert dict(tracks[0].votes) == pytest.approx({"cup": 1.9, "bottle": 0.7})
    for k in range(5, 12):  # confident bottle detections win in the end
        tracks = tracker.update(k / FPS, [noisy(p, rng, label="bottle", score=0.9)])
    assert tracks[0].label == "bottle" and tracks[0].id == 1


def test_a_detection_whose_radius_is_off_the_tracks_moves_it_little():
    """A bottle of radius 30 mm standing still; then, for 5 frames, it is partly hidden and
    the detector reports it 40 mm aside with a 67 mm circle (fitted across two objects, as
    measured in ``eval fusion``): it stays the same track, which moves a few millimetres,
    not tens, and the good detections after take it straight back. The same jumps with the
    track's own radius are believed: the track follows them."""
    import dataclasses

    p = np.array([0.4, 0.0, 0.08])
    aside = p + np.array([0.0, 0.04, 0.0])

    def run(jump_radius: float) -> tuple[list, float]:
        rng = np.random.default_rng(9)
        tracker = MultiObjectTracker()
        k = 0
        for k in range(20):
            tracker.update(k / FPS, [dataclasses.replace(noisy(p, rng), radius=0.03)])
        worst = 0.0
        for k in range(20, 25):
            m = dataclasses.replace(noisy(aside, rng), radius=jump_radius)
            tracks = tracker.update(k / FPS, [m])
            worst = max(worst, max(np.linalg.norm(tr.p_base - p) for tr in tracks))
        for k in range(25, 40):
            tracks = tracker.update(k / FPS, [dataclasses.replace(noisy(p, rng), radius=0.03)])
        return tracks, worst

    tracks, worst = run(0.067)
    assert [tr.id for tr in tracks] == [1] and worst < 0.01
    assert np.linalg.norm(tracks[0].p_base - p) < 0.003
    _, believed = run(0.03)
    assert believed > 0.02  # without the size evidence the jump moves the track


def test_association_is_globally_optimal_not_greedy():
    """Hand-worked: tracks at x = 0 and 3 cm, detections at 2.9 cm and 6 cm, 5 mm noise.
    Greedy nearest neighbour gives the 2.9 cm detection to the 3 cm track, and the 6 cm one
    is beyond the first track's gate: a new track. The optimal assignment pairs 0 -> 2.9 cm
    and 3 cm -> 6 cm, both inside their gates, and creates nothing."""
    R = np.eye(3) * 0.005**2
    tracker = MultiObjectTracker(FusionConfig(confirm_hits=1, confirm_window=1))
    at = [[0.0, 0.0, 0.1], [0.03, 0.0, 0.1]]
    tracker.update(0.0, [ObjectMeasurement(p, R, "bottle") for p in at])
    second = [ObjectMeasurement(p, R, "bottle") for p in ([0.029, 0, 0.1], [0.06, 0, 0.1])]
    cost = tracker.cost_matrix(0.033, second)
    assert cost[1, 0] < cost[0, 0] and cost[1, 0] < cost[1, 1]  # greedy's first pick
    assert cost[0, 1] > tracker.gate  # ... leaves track 1 nothing it may take
    assert cost[0, 0] < tracker.gate and cost[1, 1] < tracker.gate
    tracks = tracker.update(0.033, second)
    assert len(tracks) == 2 and tracker.reassociated == 0
    by_id = {tr.id: tr.p_base[0] for tr in tracks}
    assert 0.0 < by_id[1] < 0.029 and 0.03 < by_id[2] < 0.06


def test_measurement_from_detection_maps_the_camera_point_into_the_base_frame():
    class Detection:  # the fields of armvision.perception.detection.Detection that are used
        label, score = "cup", 0.7
        center_cam = np.array([0.05, 0.1, 0.7])

    config = FusionConfig()
    m = measurement_from_detection(Detection(), T_BASE_CAM, config)
    np.testing.assert_allclose(
        m.p_base, T_BASE_CAM[:3, :3] @ Detection.center_cam + T_BASE_CAM[:3, 3]
    )
    assert np.linalg.eigvalsh(m.R_base).min() >= config.object_sigma_floor**2 * 0.999
    assert m.label == "cup" and m.score == 0.7


def test_an_unseen_track_stops_where_it_was_last_seen() -> None:
    """A track moving at 0.1 m/s that stops being seen coasts at most 0.1 m/s x (COAST_TIME_S
    + one frame): the sum of v dt a^k, a = e^(-dt/tau), is v dt / (1 - a) ~ v (tau + dt/2);
    it does not go on at its last velocity until it is dropped."""
    from armvision.fusion.tracker import COAST_TIME_S

    tracker = MultiObjectTracker()
    p = np.array([0.3, 0.0, 0.1])
    for k in range(int(2 * FPS)):
        tracker.update(
            k / FPS,
            [ObjectMeasurement(p + np.array([0.1 * k / FPS, 0, 0]), np.eye(3) * 1e-6, "bottle")],
        )
    last = (int(2 * FPS) - 1) / FPS
    seen = tracker.tracks()[0]
    assert seen.v_base[0] == pytest.approx(0.1, abs=0.01)
    for k in range(int(2 * FPS), int(2.9 * FPS)):
        tracks = tracker.update(k / FPS, [])
    coasted = tracks[0].p_base[0] - seen.p_base[0]
    bound = 0.1 * (COAST_TIME_S + 1 / FPS)
    assert 0.0 < coasted <= bound
    assert tracks[0].v_base[0] < 0.1 * math.exp(-(0.85 - 1 / FPS) / COAST_TIME_S) * 1.5
    assert tracks[0].p_base[0] - (0.3 + 0.1 * last) < bound


def test_bad_input_raises_fusion_errors():
    tracker = MultiObjectTracker()
    with pytest.raises(FusionError, match="ObjectMeasurement"):
        tracker.update(0.0, [np.zeros(3)])
    with pytest.raises(FusionError, match="positive definite"):
        ObjectMeasurement([0, 0, 0], -np.eye(3), "bottle")
    with pytest.raises(FusionError, match="shape"):
        ObjectMeasurement([0, 0], np.eye(3), "bottle")
    with pytest.raises(FusionError, match="score"):
        ObjectMeasurement([0, 0, 0], np.eye(3), "bottle", score=2.0)
    # A frame older than the last one is stale: ignored and counted.
    tracker.update(1.0, [])
    tracker.update(0.5, [])
    assert tracker.dropped_frames == 1
