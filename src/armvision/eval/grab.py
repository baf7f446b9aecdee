"""Grasp success over random scenes: ``armvision eval grab --trials N --seed S``.

One calibration, many scenes, as a user works: the camera is calibrated once with the
gripper tag (``calibrate_sim`` at the configured camera placement, seed ``S``; the default
placement does not change between scenes) and every trial then runs with that calibration
and the same arm (the encoder zero offsets of seed ``S``). ``calibration="truth"`` uses the
simulator's camera pose instead, to separate grasping from calibration errors.

Trial k builds the scene of seed ``S + k'`` (``sim.generate_scene``: 1-4 random bottles and
cups, random sizes, fills, liquids, positions); scenes without a bottle are skipped and
counted, since there is nothing to grab. A lockstep :class:`~armvision.runtime.system.System`
runs the object detector and fusion (the tag and liquid stages are off: the grasp does not
use them, and rendering for them would only slow the evaluation), and the motion worker runs
:func:`~armvision.tasks.grab.grab` from the arm's sleep pose. Then the simulation runs 2 s
more with the arm holding still.

Success, judged by the simulator alone: at the end of those 2 s the gripper holds a bottle
(contacts on both finger pads) that stands at least 5 cm above where it started.
``time_s`` is the task's duration in simulation seconds.

Collateral, from the simulator's truth too: every object other than the one the task took
(the held one, else the one it aimed at) that moved more than :data:`COLLATERAL_MOVE_M`
(its bottom centre, from the start of the trial to the end) or tipped over (upright at the
start, not at the end), beyond what it does in the same scene, as long, with the arm holding
still (a marker lying on its side may roll by itself). A trial is collateral-free when there
is none;
``collateral_free_rate`` is the share of such trials.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any

import numpy as np

from armvision.config import Config
from armvision.errors import ConfigError

#: A trial succeeds when the held bottle is at least this much higher than at the start, m.
LIFT_SUCCESS_M = 0.05
#: ... and still held after this long, seconds.
HOLD_S = 2.0
#: Another object that moved more than this during the trial was disturbed, m.
COLLATERAL_MOVE_M = 0.02


def eval_config(config: Config) -> Config:
    """The configuration trials run with: tag and liquid stages off (see the module doc)."""
    runtime = dataclasses.replace(config.runtime, tag_detection=False, liquid_detection=False)
    return dataclasses.replace(config, runtime=runtime)


def run_trial(
    config: Config, scene_seed: int, calibration: Any, arm_seed: int | Sequence[int] | None = None
) -> dict[str, Any]:
    """One grab in the scene of ``scene_seed``; the simulator's verdict and the task's report."""
    from armvision.bench.system import sim_system, sim_world
    from armvision.tasks.grab import grab

    with sim_system(
        eval_config(config), scene_seed, calibration=calibration, arm_seed=arm_seed
    ) as system:
        world = sim_world(system)
        start_z = {o.spec.name: float(o.T_base_obj[2, 3]) for o in world.objects()}
        start_xy = {o.spec.name: o.T_base_obj[:2, 3].copy() for o in world.objects()}
        start_p = {o.spec.name: o.T_base_obj[:3, 3].copy() for o in world.objects()}
        start_up = {o.spec.name: o.upright for o in world.objects()}
        status = system.run_task("grab", grab)
        system.pump(system.clock() + HOLD_S)
        held = world.held_object()
        objects = {o.spec.name: o for o in world.objects()}
        lift = None if held is None else float(objects[held].T_base_obj[2, 3]) - start_z[held]
        kind = None if held is None else objects[held].spec.kind
        label = None if held is None else objects[held].spec.label
        ok = held is not None and label == "bottle" and lift is not None and lift >= LIFT_SUCCESS_M
        result = dict(status.result or {})
        target = result.get("target")
        aim_error_mm = None
        if target is not None:
            # The bottle the task aimed at: the object whose start position is nearest.
            name = min(start_xy, key=lambda n: np.linalg.norm(start_xy[n] - np.array(target[:2])))
            aim_error_mm = 1000.0 * float(np.linalg.norm(start_xy[name] - np.array(target[:2])))
        taken = held
        if taken is None and target is not None:
            taken = name
        alone = _unattended(config, scene_seed, world.time)
        collateral = []
        for o in objects.values():
            if o.spec.name == taken:
                continue
            # What the object did in the trial beyond what it does with the arm holding still.
            moved = float(np.linalg.norm(o.T_base_obj[:3, 3] - start_p[o.spec.name]))
            moved_alone, tipped_alone = alone[o.spec.name]
            tipped = start_up[o.spec.name] and not o.upright and not tipped_alone
            if moved - moved_alone > COLLATERAL_MOVE_M or tipped:
                collateral.append(
                    {
                        "name": o.spec.name,
                        "kind": o.spec.kind,
                        "moved_m": round(moved, 4),
                        "tipped": bool(tipped),
                    }
                )
        return {
            "seed": scene_seed,
            "success": bool(ok),
            "task_phase": status.phase,
            "task_error": status.error,
            "held": held,
            "held_kind": kind,
            "lift_m": None if lift is None else round(lift, 4),
            "time_s": None
            if status.finished is None or status.started is None
            else round(status.finished - status.started, 3),
            "aim_error_mm": None if aim_error_mm is None else round(aim_error_mm, 2),
            "objects": len(objects),
            "retries": result.get("retries"),
            "replans": result.get("replans"),
            "joint_paths_planned": result.get("joint_paths_planned"),
            "approach_deg": result.get("approach_deg"),
            "ahead_m": result.get("ahead"),
            "from_above": result.get("from_above"),
            "collateral": collateral,
        }


def _unattended(config: Config, scene_seed: int, until: float) -> dict[str, tuple[float, bool]]:
    """Per object, how far it moves and whether it tips over in the same scene, as long, with
    the arm holding still (a marker lying on its side may roll by itself): what the arm did
    not cause. Physics only, nothing rendered."""
    from armvision.sim.world import SimWorld

    with SimWorld(config, scene_seed) as world:
        start = {o.spec.name: (o.T_base_obj[:3, 3].copy(), o.upright) for o in world.objects()}
        world.run_until(until)
        return {
            o.spec.name: (
                float(np.linalg.norm(o.T_base_obj[:3, 3] - start[o.spec.name][0])),
                start[o.spec.name][1] and not o.upright,
            )
            for o in world.objects()
        }


def _trial(args: tuple[Config, int, Any, Any]) -> dict[str, Any]:
    return run_trial(*args)


def evaluate_grab(
    config: Config,
    trials: int = 50,
    seed: int = 0,
    calibration: str = "calibrate",
    progress: Callable[[int, int, dict[str, Any]], None] | None = None,
    jobs: int = 1,
) -> dict[str, Any]:
    """``trials`` grabs in random scenes from ``seed`` (see the module docstring), ``jobs``
    trials at a time (separate processes; the rows are the same whatever ``jobs``)."""
    from armvision.bench.system import calibrate_sim
    from armvision.runtime.build import result_status
    from armvision.sim.scene import generate_scene

    if trials < 1:
        raise ConfigError(f"trials must be at least 1, not {trials}")
    if calibration not in ("calibrate", "truth"):
        raise ConfigError(f"calibration must be 'calibrate' or 'truth', not {calibration!r}")
    if jobs < 1:
        raise ConfigError(f"jobs must be at least 1, not {jobs}")
    arm_seed = [seed, 0xA53]  # calibrate_sim's arm for seed S (SimArm's default stream)
    cal_report: dict[str, Any] = {"mode": calibration}
    status = None
    if calibration == "calibrate":
        result = calibrate_sim(config, seed)
        status = result_status(result)
        assert result.truth is not None  # calibrate_sim fills in the simulator's truth
        cal_report.update(
            {
                "method": result.method,
                "samples": len(result.samples),
                "residual_rms_mm": round(status.residual_mm or math.nan, 3),
                "translation_error_mm": round(result.truth["translation_error_mm"], 3),
                "rotation_error_deg": round(result.truth["rotation_error_deg"], 4),
            }
        )
    seeds: list[int] = []
    skipped: list[int] = []
    scene_seed = seed
    while len(seeds) < trials:
        scene = generate_scene(config, scene_seed)
        has_bottle = any(o.label == "bottle" for o in scene.objects)
        (seeds if has_bottle else skipped).append(scene_seed)
        scene_seed += 1
    work = [(config, s, status, arm_seed) for s in seeds]
    rows: list[dict[str, Any]] = []
    if jobs == 1:
        for args in work:
            rows.append(_trial(args))
            if progress is not None:
                progress(len(rows), trials, rows[-1])
    else:
        with ProcessPoolExecutor(jobs, mp_context=get_context("spawn")) as pool:
            for row in pool.map(_trial, work):
                rows.append(row)
                if progress is not None:
                    progress(len(rows), trials, row)
    successes = sum(r["success"] for r in rows)
    collateral_free = sum(not r["collateral"] for r in rows)
    times = [r["time_s"] for r in rows if r["success"] and r["time_s"] is not None]
    return {
        "summary": {
            "success_rate": successes / len(rows),
            "trials": len(rows),
            "successes": successes,
            "collateral_free_rate": collateral_free / len(rows),
            "collateral_free": collateral_free,
            "planner": config.grab.planner,
            "median_time_s": float(np.median(times)) if times else None,
            "skipped_scenes_without_bottle": len(skipped),
        },
        "calibration": cal_report,
        "failures": [r for r in rows if not r["success"]],
        "collateral": [r for r in rows if r["collateral"]],
        "trials": rows,
    }
