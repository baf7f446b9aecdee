"""Sorting bottles by fill over random sort scenes: ``armvision eval sort --trials N --seed S``.

As ``eval grab``: one calibration with the gripper tag (seed ``S``; ``calibration="truth"``
uses the simulator's camera pose) and one arm for every trial. Trial k builds the sort
profile's scene of seed ``S + k`` (``sim.profile = "sort"``, :func:`~armvision.sim.scene.
generate_sort_scene`: 2-4 bottles whose liquid shows, with true fills either side of
``sort.fill_threshold``, among distractors, 1-5 cm apart), runs :func:`~armvision.tasks.sort.
sort` by fill on a lockstep system (tag and liquid stages off: the sort measures with the
analyze task's own meter) from the arm's sleep pose, then 2 s more with the arm still.

Judged by the simulator alone, per bottle: it is **right** when it ends upright inside the
rectangle of the zone its *true* fill chooses (below the threshold ``sort.below``, else
``sort.above``); ``right_zone_rate`` is the share of right bottles over every bottle of every
trial. Per placement (every bottle the sort set down, from the spot it asked for): the true
distance of the nearest object's centre to that spot and whether it stands upright;
``placed_upright_within_2cm_rate`` the share upright within :data:`PLACE_TOLERANCE_M`.
Collateral as in ``eval grab`` (:mod:`armvision.eval.grab`): every object the sort did not
take (the bottles it set down or picked up to present are taken) that moved more than 2 cm or
tipped, beyond what it does with the arm still; ``collateral_free_rate`` the share of trials
without. ``total_time_s`` sums the sort tasks' durations (simulation seconds).
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
from armvision.eval.grab import COLLATERAL_MOVE_M, HOLD_S, _unattended, eval_config

#: A placement counts as accurate when the bottle's centre ends this near the asked spot, m.
PLACE_TOLERANCE_M = 0.02
#: A sort's report is matched to the simulated bottle that started this near it, m.
MATCH_M = 0.06


def sort_config(config: Config) -> Config:
    """The configuration trials run with: the sort profile, tag and liquid stages off."""
    config = eval_config(config)
    return dataclasses.replace(config, sim=dataclasses.replace(config.sim, profile="sort"))


def _in_rect(xy: np.ndarray, rect: tuple[float, float, float, float]) -> bool:
    x0, y0, x1, y1 = rect
    return bool(x0 <= xy[0] <= x1 and y0 <= xy[1] <= y1)


def run_trial(
    config: Config, scene_seed: int, calibration: Any, arm_seed: int | Sequence[int] | None = None
) -> dict[str, Any]:
    """One sort in the sort scene of ``scene_seed``; per bottle the simulator's verdict."""
    from armvision.bench.system import sim_system, sim_world
    from armvision.tasks.sort import sort

    config = sort_config(config)
    zones, rule = config.place.zones, config.sort
    with sim_system(config, scene_seed, calibration=calibration, arm_seed=arm_seed) as system:
        world = sim_world(system)
        start_p = {o.spec.name: o.T_base_obj[:3, 3].copy() for o in world.objects()}
        start_up = {o.spec.name: o.upright for o in world.objects()}
        status = system.run_task("sort", sort, by="fill")
        system.pump(system.clock() + HOLD_S)
        objects = {o.spec.name: o for o in world.objects()}
        result = dict(status.result or {})
        reports = list(result.get("bottles") or [])
        # Which simulated object each report is about (where it started).
        taken: set[str] = set()
        by_name: dict[str, dict[str, Any]] = {}
        for rep in reports:
            name = min(start_p, key=lambda n: math.dist(start_p[n][:2], rep["start"]))
            if math.dist(start_p[name][:2], rep["start"]) < MATCH_M:
                by_name[name] = rep
                if rep["action"] in ("placed", "failed") or rep.get("picked"):
                    taken.add(name)
        bottles = []
        for name, o in objects.items():
            if o.spec.label != "bottle":
                continue
            want = rule.below if o.spec.fill < rule.fill_threshold else rule.above
            xy = o.T_base_obj[:2, 3]
            right = bool(o.upright and _in_rect(xy, zones[want]))
            rep = by_name.get(name)
            bottles.append(
                {
                    "name": name,
                    "kind": o.spec.kind,
                    "true_fill": round(o.spec.fill, 4),
                    "measured_fill": None if rep is None else rep["fill"],
                    "want_zone": want,
                    "chose_zone": None if rep is None else rep["zone"],
                    "action": None if rep is None else rep["action"],
                    "reason": None if rep is None else rep["reason"],
                    "right": right,
                    "upright": bool(o.upright),
                    "end": [round(float(v), 4) for v in xy],
                }
            )
        placements = []
        for rep in reports:
            asked = (rep.get("place") or {}).get("asked")
            if asked is None or not (rep.get("place") or {}).get("released"):
                continue
            name = min(objects, key=lambda n: math.dist(objects[n].T_base_obj[:2, 3], asked))
            err = math.dist(objects[name].T_base_obj[:2, 3], asked)
            placements.append(
                {
                    "name": name,
                    "asked": asked,
                    "error_m": round(err, 4),
                    "upright": bool(objects[name].upright),
                    "tracked_error_m": rep["place"].get("error_m"),
                }
            )
        taken |= {p["name"] for p in placements}  # what it set down was taken, whatever report
        alone = _unattended(config, scene_seed, world.time)
        collateral = []
        for name, o in objects.items():
            if name in taken:
                continue
            moved = float(np.linalg.norm(o.T_base_obj[:3, 3] - start_p[name]))
            moved_alone, tipped_alone = alone[name]
            tipped = start_up[name] and not o.upright and not tipped_alone
            if moved - moved_alone > COLLATERAL_MOVE_M or tipped:
                collateral.append(
                    {
                        "name": name,
                        "kind": o.spec.kind,
                        "moved_m": round(moved, 4),
                        "tipped": bool(tipped),
                    }
                )
        time_s = (
            None
            if status.finished is None or status.started is None
            else round(status.finished - status.started, 3)
        )
        return {
            "seed": scene_seed,
            "task_phase": status.phase,
            "task_error": status.error,
            "bottles": bottles,
            "placements": placements,
            "collateral": collateral,
            "time_s": time_s,
            "objects": len(objects),
        }


def _trial(args: tuple[Config, int, Any, Any]) -> dict[str, Any]:
    return run_trial(*args)


def evaluate_sort(
    config: Config,
    trials: int = 20,
    seed: int = 0,
    calibration: str = "calibrate",
    jobs: int = 1,
    progress: Callable[[int, int, dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """``trials`` sorts in sort scenes from ``seed`` (see the module docstring), ``jobs``
    trials at a time (separate processes)."""
    from armvision.bench.system import calibrate_sim
    from armvision.runtime.build import result_status

    if trials < 1:
        raise ConfigError(f"trials must be at least 1, not {trials}")
    if jobs < 1:
        raise ConfigError(f"jobs must be at least 1, not {jobs}")
    if calibration not in ("calibrate", "truth"):
        raise ConfigError(f"calibration must be 'calibrate' or 'truth', not {calibration!r}")
    arm_seed = [seed, 0xA53]
    cal_report: dict[str, Any] = {"mode": calibration}
    status = None
    if calibration == "calibrate":
        result = calibrate_sim(config, seed)
        status = result_status(result)
        assert result.truth is not None
        cal_report.update(
            {
                "method": result.method,
                "residual_rms_mm": round(status.residual_mm or math.nan, 3),
                "translation_error_mm": round(result.truth["translation_error_mm"], 3),
                "rotation_error_deg": round(result.truth["rotation_error_deg"], 4),
            }
        )
    work = [(config, seed + k, status, arm_seed) for k in range(trials)]
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
    bottles = [b for r in rows for b in r["bottles"]]
    placements = [p for r in rows for p in r["placements"]]
    right = sum(b["right"] for b in bottles)
    good = [p for p in placements if p["upright"] and p["error_m"] <= PLACE_TOLERANCE_M]
    errors = [p["error_m"] for p in placements]
    times = [r["time_s"] for r in rows if r["time_s"] is not None]
    collateral_free = sum(not r["collateral"] for r in rows)
    return {
        "summary": {
            "right_zone_rate": right / len(bottles) if bottles else None,
            "bottles": len(bottles),
            "right_zone": right,
            "trials": len(rows),
            "collateral_free_rate": collateral_free / len(rows),
            "collateral_objects": sum(len(r["collateral"]) for r in rows),
            "placements": len(placements),
            "placed_upright_within_2cm_rate": len(good) / len(placements) if placements else None,
            "placed_upright_rate": (
                sum(p["upright"] for p in placements) / len(placements) if placements else None
            ),
            "place_error_median_m": float(np.median(errors)) if errors else None,
            "place_error_max_m": float(np.max(errors)) if errors else None,
            "total_time_s": round(float(sum(times)), 1),
            "median_trial_time_s": float(np.median(times)) if times else None,
        },
        "calibration": cal_report,
        "wrong": [dict(b, seed=r["seed"]) for r in rows for b in r["bottles"] if not b["right"]],
        "collateral": [r for r in rows if r["collateral"]],
        "trials": rows,
    }
