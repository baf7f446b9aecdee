"""IK success rate and speed: armvision's closed-form IK beside Interbotix's modern_robotics IK.

Targets are fk of random in-limit ViperX-300s configurations, so every one is reachable.
Interbotix's ``set_ee_pose_matrix`` runs ``modern_robotics.IKinSpace(Slist, M, T, guess,
eomg=0.001, ev=0.001)`` from the guesses [0]*6 and waist -120 / +120 deg, wraps the angles and
checks the joint limits (its velocity check passes for a 2 s move from home); that is
reproduced here. "verified" means fk of the answer is within 0.1 mm and 0.01 deg of the target
and the answer is within the joint limits, judged by the same code for both.

    python benchmarks/bench_ik.py [--n 10000] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import modern_robotics as mr
import numpy as np

from armvision.geometry import pose_error
from armvision.robot.kinematics import (
    ORIENTATION_TOLERANCE_RAD,
    POSITION_TOLERANCE_M,
    VX300S,
    fk,
    ik,
)

INTERBOTIX_GUESSES = [
    np.zeros(6),
    np.array([np.deg2rad(-120), 0, 0, 0, 0, 0]),
    np.array([np.deg2rad(120), 0, 0, 0, 0, 0]),
]


def interbotix_ik(T_target: np.ndarray) -> tuple[np.ndarray, bool]:
    """What InterbotixArmXSInterface.set_ee_pose_matrix would compute (ROS 2 humble)."""
    rev = 2 * np.pi
    theta = INTERBOTIX_GUESSES[0]
    for guess in INTERBOTIX_GUESSES:
        theta, success = mr.IKinSpace(VX300S.Slist.T, VX300S.M, T_target, guess, 0.001, 0.001)
        if not success:
            continue
        theta = np.array(theta, dtype=float)
        for i in range(6):  # Interbotix's wrapping into the limits
            if theta[i] <= -rev:
                theta[i] %= -rev
            elif theta[i] >= rev:
                theta[i] %= rev
            if round(theta[i], 3) < round(VX300S.lower[i], 3):
                theta[i] += rev
            elif round(theta[i], 3) > round(VX300S.upper[i], 3):
                theta[i] -= rev
        truncated = np.trunc(theta * 1000) / 1000.0  # check_joint_limits truncates to mrad
        if np.all(truncated >= VX300S.lower) and np.all(truncated <= VX300S.upper):
            return theta, True
    return theta, False


def verified(q: np.ndarray, T_target: np.ndarray) -> bool:
    dp, dr = pose_error(fk(q), T_target)
    return bool(
        dp <= POSITION_TOLERANCE_M and dr <= ORIENTATION_TOLERANCE_RAD and VX300S.within_limits(q)
    )


def run(solver, targets: np.ndarray) -> dict:
    times, reported, good = [], 0, 0
    for T in targets:
        t0 = time.perf_counter()
        q, ok = solver(T)
        times.append(time.perf_counter() - t0)
        reported += ok
        good += ok and verified(q, T)
    n = len(targets)
    return {
        "reported_ok_pct": 100.0 * reported / n,
        "verified_ok_pct": 100.0 * good / n,
        "median_ms": 1e3 * float(np.median(times)),
        "p95_ms": 1e3 * float(np.percentile(times, 95)),
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=10_000, help="number of targets")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    targets = fk(rng.uniform(VX300S.lower, VX300S.upper, size=(args.n, 6)))
    rows = {
        "armvision ik (closed form)": run(lambda T: ik(T), targets),
        "Interbotix (mr.IKinSpace, 3 seeds)": run(interbotix_ik, targets),
    }
    print(
        f"\nIK on {args.n} reachable ViperX-300s poses (fk of random in-limit configurations, "
        f"seed {args.seed})\n"
    )
    print("| solver | reported ok | verified ok (0.1 mm, 0.01 deg, limits) | median ms | p95 ms |")
    print("|---|---:|---:|---:|---:|")
    for name, r in rows.items():
        print(
            f"| {name} | {r['reported_ok_pct']:.2f} % | {r['verified_ok_pct']:.2f} % "
            f"| {r['median_ms']:.3f} | {r['p95_ms']:.3f} |"
        )
    return rows


if __name__ == "__main__":
    main()
