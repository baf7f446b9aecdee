"""Simulation speed: physics as a multiple of real time, and RGB-D frames per second.

    python benchmarks/bench_sim.py [--sim-seconds 20] [--frames 60] [--seed 0]

Physics runs in lockstep with no rendering, on a scene with four objects: once idle (servos
holding) and once with SimArm moving back and forth between two poses (the trajectory is
sampled before every 2 ms step). The camera rows time ``SimCamera.read()`` at the configured
resolution (640x480): one simulation frame period of physics, one OpenGL render of colour and
depth (Mesa's llvmpipe with no GPU), and the D435 depth model. Targets (issue 3): physics
>= 20x real time, RGB-D >= 10 frames/s on 2 cores without a GPU.
"""

from __future__ import annotations

import argparse
import os
import time

from armvision.config import Config, SimConfig
from armvision.sim.arm import SimArm
from armvision.sim.camera import SimCamera, realsense_depth_model
from armvision.sim.world import SimWorld

PHYSICS_TARGET_X = 20.0
FPS_TARGET = 10.0


def _busy_world(seed: int) -> SimWorld:
    return SimWorld(Config(sim=SimConfig(min_objects=4, max_objects=4)), seed=seed)


def physics_idle(sim_seconds: float, seed: int) -> float:
    """Simulated seconds per wall-clock second with the arm holding still."""
    world = _busy_world(seed)
    start = time.perf_counter()
    world.advance(sim_seconds)
    return sim_seconds / (time.perf_counter() - start)


def physics_moving(sim_seconds: float, seed: int) -> float:
    """Simulated seconds per wall-clock second while SimArm executes trajectories."""
    world = _busy_world(seed)
    arm = SimArm(world)
    poses = ([0.5, -0.4, 0.3, 0.2, 0.6, -0.3], [-0.5, 0.1, -0.2, -0.2, 0.9, 0.3])
    start_sim, start = world.time, time.perf_counter()
    k = 0
    while world.time - start_sim < sim_seconds:
        arm.set_joint_positions(poses[k % 2], moving_time=1.5, accel_time=0.3)
        k += 1
    return (world.time - start_sim) / (time.perf_counter() - start)


def camera_rates(frames: int, seed: int) -> dict[str, float]:
    """Frames per second of SimCamera.read() and of its parts."""
    world = _busy_world(seed)
    with SimCamera(world) as camera:
        camera.read()  # the first render compiles shaders and uploads textures
        start = time.perf_counter()
        for _ in range(frames):
            camera.read()
        read_s = (time.perf_counter() - start) / frames
        renderer = camera._renderer
        assert renderer is not None
        start = time.perf_counter()
        for _ in range(frames):
            with world.lock:
                renderer.update(world.data)
            _, z = renderer.render()
        render_s = (time.perf_counter() - start) / frames
    start = time.perf_counter()
    for _ in range(frames):
        realsense_depth_model(z, camera._rng)
    model_s = (time.perf_counter() - start) / frames
    return {"read": 1.0 / read_s, "render": 1.0 / render_s, "depth_model": 1.0 / model_s}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sim-seconds", type=float, default=20.0, help="simulated time per run")
    parser.add_argument("--frames", type=int, default=60, help="frames to time")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    idle = physics_idle(args.sim_seconds, args.seed)
    moving = physics_moving(args.sim_seconds, args.seed)
    cam = camera_rates(args.frames, args.seed)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    config = Config()
    size = f"{config.camera.width}x{config.camera.height}"

    rows = [
        ("physics, arm holding (x real time)", f"{idle:.1f}", f">= {PHYSICS_TARGET_X:.0f}"),
        ("physics, arm moving (x real time)", f"{moving:.1f}", f">= {PHYSICS_TARGET_X:.0f}"),
        (f"RGB-D frames/s, SimCamera.read() {size}", f"{cam['read']:.1f}", f">= {FPS_TARGET:.0f}"),
        (f"  render only (colour + depth) {size}", f"{cam['render']:.1f}", ""),
        ("  depth noise model only", f"{cam['depth_model']:.1f}", ""),
    ]
    print(f"Simulation speed ({cores} cores, MUJOCO_GL={os.environ.get('MUJOCO_GL')})")
    width = max(len(r[0]) for r in rows)
    print(f"{'measure':<{width}}  {'value':>8}  target")
    for name, value, target in rows:
        print(f"{name:<{width}}  {value:>8}  {target}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
