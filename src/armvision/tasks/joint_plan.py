"""Joint-space paths around the planning scene: a straight joint line when it is free, else
OMPL's RRT-Connect (the ``ompl`` package), then timed within the joint speed limits.

:func:`joint_path` answers a list of configurations from start to goal whose joint-space
lines are all at least the asked clearance from the scene (checked every
:data:`~armvision.tasks.grasp_plan.LINE_STEP_RAD`), or None when the planner finds none in
its time. That time is the planning thread's own processor time (capped at
:data:`WALL_FACTOR` times as much on the clock): on a machine busy with other threads (the
realtime simulation's physics, camera and detectors on 2 cores) a budget on the clock left
RRT-Connect a fraction of it and a free path went unfound. :func:`path_times` gives each
line's duration: the joint that moves most at :data:`~armvision.tasks.motion.SPEED_FRACTION`
of its velocity limit, plus the arm's acceleration time, and at least
:data:`~armvision.tasks.motion.SEGMENT_TIME_S`.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from armvision.robot.kinematics import ArmModel
from armvision.tasks.grasp_plan import joint_line
from armvision.tasks.motion import SEGMENT_TIME_S, SPEED_FRACTION

Array = NDArray[np.float64]

#: OMPL checks the motions between its states every this share of the joint space's extent.
OMPL_RESOLUTION = 0.002
#: Time spent shortening the found path (OMPL's path simplifier), seconds.
SIMPLIFY_S = 0.3
#: A planning budget of t seconds of processor time ends after WALL_FACTOR * t on the clock.
WALL_FACTOR = 5.0


def _budget(ob: Any, seconds: float) -> Any:
    """An OMPL termination condition: ``seconds`` of this thread's processor time, or
    WALL_FACTOR times as many on the clock, whichever comes first."""
    cpu0, wall0 = time.thread_time(), time.monotonic()
    wall = WALL_FACTOR * seconds
    return ob.PlannerTerminationCondition(
        lambda: time.thread_time() - cpu0 > seconds or time.monotonic() - wall0 > wall
    )


def path_free(path: list[Array], least: Callable[[Array], float], needed: float) -> bool:
    """Whether every joint line of ``path`` keeps ``needed`` clearance (``least`` gives the
    least clearance over a batch of configurations)."""
    return all(least(joint_line(a, b)) >= needed for a, b in itertools.pairwise(path))


def joint_path(
    q_start: Array,
    q_goal: Array,
    least: Callable[[Array], float],
    needed: float,
    model: ArmModel,
    time_s: float,
    seed: int = 0,
) -> list[Array] | None:
    """Configurations from ``q_start`` to ``q_goal`` whose joint lines keep ``needed``
    clearance (``least(Q)`` is the least clearance of the configurations Q (N, 6)); the
    straight line if it is free, else RRT-Connect's path, simplified and checked again;
    None if none is found within ``time_s``."""
    q_start = np.asarray(q_start, dtype=float)
    q_goal = np.asarray(q_goal, dtype=float)
    if path_free([q_start, q_goal], least, needed):
        return [q_start, q_goal]
    if least(q_start[None]) < needed or least(q_goal[None]) < needed:
        return None
    found = _rrt_connect(q_start, q_goal, least, needed, model, time_s, seed)
    if found is None or not path_free(found, least, needed):
        return None
    return found


def _rrt_connect(
    q_start: Array,
    q_goal: Array,
    least: Callable[[Array], float],
    needed: float,
    model: ArmModel,
    time_s: float,
    seed: int,
) -> list[Array] | None:
    """RRT-Connect through OMPL in the joint limits' box; the path, simplified, or None."""
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    ou.setLogLevel(ou.LOG_WARN)
    ou.RNG.setSeed(int(seed) + 1)
    dof = model.dof
    space = ob.RealVectorStateSpace(dof)
    bounds = ob.RealVectorBounds(dof)
    for j in range(dof):
        bounds.setLow(j, float(model.lower[j]))
        bounds.setHigh(j, float(model.upper[j]))
    space.setBounds(bounds)
    setup = og.SimpleSetup(space)

    def valid(state: Any) -> bool:
        q = np.array([float(state[j]) for j in range(dof)], dtype=np.float64)
        return bool(least(q[None]) >= needed)

    setup.setStateValidityChecker(valid)
    start, goal = space.allocState(), space.allocState()
    for j in range(dof):
        start[j], goal[j] = float(q_start[j]), float(q_goal[j])
    setup.setStartAndGoalStates(start, goal)
    info = setup.getSpaceInformation()
    info.setStateValidityCheckingResolution(OMPL_RESOLUTION)
    setup.setPlanner(og.RRTConnect(info))
    solved = setup.solve(_budget(ob, float(time_s)))
    if not solved or not setup.haveExactSolutionPath():
        return None
    setup.simplifySolution(_budget(ob, SIMPLIFY_S))
    path = setup.getSolutionPath()
    out = [
        np.array([path.getState(k)[j] for j in range(dof)], dtype=float)
        for k in range(path.getStateCount())
    ]
    out[0], out[-1] = q_start, q_goal
    return out


def path_times(path: list[Array], model: ArmModel, accel_time: float) -> list[float]:
    """Duration of each joint line of ``path`` within the speed limits (module docstring)."""
    limit = SPEED_FRACTION * np.asarray(model.velocity, dtype=float)
    return [
        max(SEGMENT_TIME_S, float(np.max(np.abs(b - a) / limit)) + accel_time)
        for a, b in itertools.pairwise(path)
    ]
