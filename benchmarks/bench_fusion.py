"""Cost of the Kalman filters and the tracker (issue 6), beside filterpy in the same run.

Per filter update: our end-effector filter (21 states with the joint offsets and the camera
correction; an encoder reading, and a tag pose that arrives 20 ms late and is replayed), our
6-state object filter, the paper's 7-state filter and filterpy's ``KalmanFilter`` with the
same 7-state matrices (predict + update each). Per tracker cycle: one frame of detections
with 1 and with 20 objects in view. Times are medians over repeated runs, microseconds.

    python benchmarks/bench_fusion.py [--n 2000]
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

import numpy as np
from filterpy.kalman import KalmanFilter

from armvision.config import FusionConfig
from armvision.fusion.kalman import EEFilter, Measurement, MotionFilter, PaperKF
from armvision.fusion.tracker import MultiObjectTracker, ObjectMeasurement
from armvision.geometry import inv_T, make_T, rpy_to_R
from armvision.robot.kinematics import fk

T_BASE_CAM = make_T(rpy_to_R(-2.1, 0.0, math.pi / 2), [1.0, 0.0, 0.45])
T_EE_TAG = make_T(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), [-0.1, 0, 0.03])


def median_us(run: Callable[[int], None], n: int, repeats: int = 5) -> float:
    """Median over ``repeats`` of the mean time per call of ``run(i)`` for i < n, in us."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for i in range(n):
            run(i)
        times.append((time.perf_counter() - t0) / n)
    return 1e6 * float(np.median(times))


def q_at(t: float) -> np.ndarray:
    return np.array([0.2 * math.sin(t), -0.3, 0.4, 0.1 * math.cos(t), 0.9, 0.0])


def _tracker_cycle(tracker: MultiObjectTracker, frames: list) -> Callable[[int], None]:
    """One tracker update per call, on the next of ``frames`` (after 10 warm-up frames)."""
    state = {"k": 10}

    def cycle(_: int) -> None:
        tracker.update(state["k"] / 30.0, frames[state["k"] % len(frames)])
        state["k"] += 1

    return cycle


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=2000, help="calls per timing run")
    args = parser.parse_args(argv)
    n = args.n
    config = FusionConfig()
    dt = 1.0 / config.rate_hz
    rows: dict[str, float] = {}

    # Our end-effector filter: encoder readings every tick, a tag pose every third tick.
    ee = EEFilter(config, T_BASE_CAM, T_EE_TAG)
    T_cam_base = inv_T(T_BASE_CAM)
    ticks = [(k * dt, q_at(k * dt)) for k in range(3 * n + 10)]
    for t, q in ticks[:10]:
        ee.update_encoders(t, q)
    state = {"k": 10}

    def ee_encoders(_: int) -> None:
        t, q = ticks[state["k"] % len(ticks)]
        ee.update_encoders(t + dt * len(ticks) * (state["k"] // len(ticks)), q)
        state["k"] += 1

    rows["ours: end effector, encoder reading (21 states)"] = median_us(ee_encoders, n)
    ee2 = EEFilter(config, T_BASE_CAM, T_EE_TAG)
    clock = {"t": 0.0}

    def ee_tag_late(_: int) -> None:
        # Two encoder ticks, then the tag pose of a frame 20 ms old: inserted and replayed.
        for _ in range(2):
            clock["t"] += dt
            ee2.update_encoders(clock["t"], q_at(clock["t"]))
        t_frame = clock["t"] - 0.02
        ee2.update_camera(t_frame, T_cam_base @ fk(q_at(t_frame)) @ T_EE_TAG)

    for i in range(20):
        ee_tag_late(i)
    per_cycle = median_us(ee_tag_late, max(n // 3, 1))
    per_encoder = rows["ours: end effector, encoder reading (21 states)"]
    rows["ours: end effector, tag pose 20 ms late (with replay)"] = per_cycle - 2 * per_encoder

    # Our object filter (constant velocity, 6 states): predict + update.
    obj = MotionFilter(noise_density=config.object_accel_noise, gate_probability=None)
    obj.initialize(0.0, np.zeros(6), np.eye(6) * 1e-4)
    H = np.hstack([np.eye(3), np.zeros((3, 3))])
    rng = np.random.default_rng(0)
    zs = rng.normal(0, 0.002, (n, 3))
    R = np.eye(3) * 4e-6
    t_obj = {"t": 0.0}

    def object_update(i: int) -> None:
        t_obj["t"] += 1.0 / 30.0
        obj.predict(t_obj["t"])
        obj.update([Measurement("camera", zs[i], H, R)], gate=False)

    rows["ours: object filter, predict + update (6 states)"] = median_us(object_update, n)

    # The paper's filter and filterpy with the same matrices: predict + encoder update.
    paper = PaperKF(T_BASE_CAM, dt=dt)
    ref = KalmanFilter(dim_x=7, dim_z=4)
    ref.x, ref.P, ref.F, ref.Q = paper.x.reshape(7, 1), paper.P.copy(), paper.A, paper.Q
    ys = [np.append(fk(q_at(k * dt))[:3, 3], 1.0) for k in range(n)]

    def paper_step(i: int) -> None:
        paper.predict()
        paper._update(ys[i], paper.C1, paper.R1)

    def filterpy_step(i: int) -> None:
        ref.predict()
        ref.update(ys[i].reshape(4, 1), R=paper.R1, H=paper.C1)

    rows["PaperKF: predict + update (7 states)"] = median_us(paper_step, n)
    rows["filterpy KalmanFilter: predict + update (same 7 states)"] = median_us(filterpy_step, n)

    # The tracker: one frame of detections, steady state.
    for count in (1, 20):
        tracker = MultiObjectTracker(config)
        grid = np.array(
            [[0.25 + 0.08 * (i % 5), -0.3 + 0.15 * (i // 5), 0.1] for i in range(count)]
        )
        frames = [
            [ObjectMeasurement(p + rng.normal(0, 0.002, 3), R, "bottle") for p in grid]
            for _ in range(64)
        ]
        for k in range(10):
            tracker.update(k / 30.0, frames[k])
        rows[f"tracker: one frame, {count} object{'s' if count > 1 else ''}"] = median_us(
            _tracker_cycle(tracker, frames), max(n // (10 * count), 20)
        )
        assert len(tracker.tracks()) == count  # every object tracked, nothing spurious

    print(f"\nFusion cost per call, median of 5 runs (microseconds), {n} calls per run\n")
    print("| operation | us per call |")
    print("|---|---:|")
    for name, value in rows.items():
        print(f"| {name} | {value:.1f} |")
    budget = 1e6 / config.rate_hz
    print(f"\n(the fusion loop's period at {config.rate_hz:.0f} Hz is {budget:.0f} us)")
    return rows


if __name__ == "__main__":
    main()
