"""Joint-state reads through the Dynamixel driver and the servo-bus emulator (issue 20).

    python benchmarks/bench_dynamixel.py [--seconds 3] [--latency-ms 16]

Everything is real but the servos: ROBOTIS's dynamixel-sdk on a pseudo-terminal, the emulator
(:mod:`armvision.sim.servo_bus`) answering from a realtime SimWorld, all in one process on the
machine's cores. Rows: one GroupSyncRead-style read of Present_Current/Velocity/Position of all
nine servos back to back (the bus's ceiling here), the driver's state thread (asked for 200 Hz)
with the arm holding and while it moves, and a move's sync write. Target: >= 100 Hz of joint
state. A real U2D2 at 1 Mbps spends ~0.3 ms on the wire per servo answer; the emulator's answers
cost Python time instead, so the figures say what the driver sustains, not what the wire does.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from armvision.config import Config
from armvision.robot import xseries as xs
from armvision.robot.dynamixel import DynamixelArm
from armvision.sim.servo_bus import ServoBusEmulator
from armvision.sim.world import SimWorld

TARGET_HZ = 100.0


def _world() -> SimWorld:
    c = Config()
    sim = dataclasses.replace(c.sim, min_objects=0, max_objects=0, loose_tags=0)
    return SimWorld(dataclasses.replace(c, sim=sim), 0, mode="realtime")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--latency-ms", type=float, default=16.0, help="packet latency timer")
    args = parser.parse_args(argv)

    world = _world()
    bus = ServoBusEmulator(world).start()
    arm = DynamixelArm(bus.port, latency_ms=args.latency_ms)
    rows: list[tuple[str, str]] = []
    try:
        # Back-to-back reads with the state thread paused (it waits on the bus lock).
        addr, size = xs.STATE_BLOCK
        ids = [s.id for s in xs.VX300S_BUS]
        n = failed = 0
        with arm.bus.lock:
            start = time.perf_counter()
            while time.perf_counter() - start < args.seconds:
                _, _, bad = arm.bus.sync_read(ids, addr, size)
                n += 1
                failed += bool(bad)
            elapsed = time.perf_counter() - start
        rows.append(("sync read, 9 servos x 10 bytes, back to back", f"{n / elapsed:.0f} Hz"))
        rows.append(("  reads that failed", f"{failed} of {n}"))

        def thread_rate(seconds: float) -> float:
            r0, t0 = arm.reads, time.perf_counter()
            time.sleep(seconds)
            return (arm.reads - r0) / (time.perf_counter() - t0)

        holding = thread_rate(args.seconds)
        rows.append(("driver state thread, arm holding (asks 200 Hz)", f"{holding:.0f} Hz"))
        q = np.array([0.6, -0.3, 0.4, 0.2, -0.5, 0.3])
        t0 = time.perf_counter()
        arm.set_joint_positions(q, moving_time=args.seconds, accel_time=0.3, blocking=False)
        send_ms = (time.perf_counter() - t0) * 1000.0
        moving = thread_rate(args.seconds * 0.9)
        rows.append(("driver state thread, arm moving", f"{moving:.0f} Hz"))
        rows.append(("move command (checks + one sync write)", f"{send_ms:.1f} ms"))
        time.sleep(0.3)
        err = float(np.abs(world.joint_positions() - q).max())
        rows.append(("move reached (simulator truth), max joint error", f"{err * 1000:.2f} mrad"))
        rows.append(("emulator: packets handled", f"{bus.packets}"))
    finally:
        arm.close()
        bus.close()
        world.close()
    width = max(len(r[0]) for r in rows)
    print(f"Dynamixel bus through the emulator (latency timer {args.latency_ms:g} ms)")
    for name, value in rows:
        print(f"  {name:<{width}}  {value}")
    print(f"  target: joint state >= {TARGET_HZ:.0f} Hz")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
