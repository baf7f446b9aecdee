"""Following a moving tag, against the simulator: ``armvision eval follow --seed S``.

**Scene.** The seed's camera placement, no objects, and one loose AprilTag (id
``follow.tag_id``, the gripper tag's size and family) lying on the table. From the start of the
follow task the tag slides along a circle of ``radius`` (6 cm) around ``center`` (0.45, 0) m
(base frame) at ``speed`` (10 cm/s), its orientation fixed (it slides, it does not turn).
The start angle, the direction of travel and the tag's yaw are seeded. A world controller
moves it before every physics step (:meth:`~armvision.sim.world.SimWorld.set_loose_tag_pose`),
so it moves smoothly between camera frames. The whole circle is checked to be in the
camera's view and every desired pose on it to be reachable before anything runs.

**Runs.** For each mode (``servo``, then ``blocking``) a fresh lockstep
:func:`~armvision.bench.system.sim_system` of the same seed (same scene, same encoder
offsets): object and liquid detection off (nothing to see; it saves rendering), the tag stage
at ``runtime.tag_hz``, fusion at ``fusion.rate_hz``. The arm is first put at the desired pose
for the tag's start position (tag detection off meanwhile), the stages run 0.5 s, then
:func:`armvision.tasks.follow.follow` runs for ``duration_s`` (default
``follow.duration_s``, 20 s) while the tag moves.

**Calibration.** The runtime gets the true camera pose perturbed by a seeded error of
``calibration_error`` = (metres, degrees), as :func:`armvision.eval.fusion.perturbed_calibration`
does (the accuracy the calibration targets); ``calibration_error=None`` gives it the simulator's
true camera pose. The JSON says which under ``"calibration"``.

**Error.** At every fusion period (1/``fusion.rate_hz`` of simulation time, sampled by the same
world controller): the simulator's true end-effector position minus the desired position
computed from the tag's *true* pose by the task's own rule
(:func:`~armvision.tasks.follow.desired_ee_pose`: ``follow.standoff`` back toward the base,
``follow.height_offset`` up). RMS and max over the samples from ``settle_s`` (2 s: the servo's
start-up and the estimator's first window) to the end of ``duration_s``; the blocking mode's
last move may run past the end and is not scored there.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from armvision.camera.frames import project
from armvision.config import Config
from armvision.errors import ConfigError
from armvision.eval.fusion import perturbed_calibration
from armvision.geometry import inv_T, make_T, rot_z
from armvision.robot.kinematics import VX300S, ik
from armvision.tasks.follow import desired_ee_pose, follow

Array = NDArray[np.float64]

#: The tag must project at least this far inside the image everywhere on its circle, pixels.
VIEW_MARGIN_PX = 40.0
#: The stages run this long before the follow starts (first tag detections), seconds.
WARM_UP_S = 0.5
MODES = ("servo", "blocking")


#: Free table left between the sliding tag and any object standing near its circle, m.
PATH_CLEARANCE_M = 0.01


def circle_path(
    center: tuple[float, float],
    radius: float,
    speed: float,
    phase: float,
    direction: float,
    yaw: float,
) -> Callable[[float], Array]:
    """``T_base_tag(t)``: a tag lying face up on the table (z into the tag, pointing down),
    its centre going round ``center`` on ``radius`` m at ``speed`` m/s from angle ``phase``
    (rad), counter-clockwise for ``direction`` +1, clockwise for -1; its yaw fixed at ``yaw``
    (rad, as :class:`~armvision.sim.world.LooseTag`); t < 0 is the start."""
    omega = direction * speed / radius
    # Face up: the tag's z (into the tag) points down, as SimWorld lays loose tags.
    R_base_tag = rot_z(yaw) @ np.diag([1.0, -1.0, -1.0])
    z = 0.001  # the plate's top, just above the table

    def at(t: float) -> Array:
        a = phase + omega * max(t, 0.0)
        return make_T(
            R_base_tag,
            [center[0] + radius * math.cos(a), center[1] + radius * math.sin(a), z],
        )

    return at


def _rms_mm(errors: Array) -> float:
    if len(errors) == 0:
        return math.nan
    return 1000.0 * math.sqrt(float(np.mean(np.sum(errors**2, axis=1))))


def _check_path(
    config: Config, T_base_cam: Array, intr: Any, path: Callable[[float], Array], lap: float
) -> None:
    """Every point of one lap in view and every desired pose on it reachable, or raise."""
    follow_cfg = config.follow
    T_cam_base = inv_T(T_base_cam)
    q_seed = np.zeros(VX300S.dof)
    for t in np.linspace(0.0, lap, 72, endpoint=False):
        T_base_tag = path(float(t))
        p_cam = (T_cam_base @ T_base_tag)[:3, 3]
        u, v = project(intr, p_cam[None])[0]
        inside = (
            p_cam[2] > 0.0
            and VIEW_MARGIN_PX < u < intr.width - VIEW_MARGIN_PX
            and VIEW_MARGIN_PX < v < intr.height - VIEW_MARGIN_PX
        )
        if not inside:
            raise ConfigError(
                f"the tag's circle leaves the camera's view at {T_base_tag[:3, 3].round(3)} m: "
                "choose another center or radius"
            )
        T_des = desired_ee_pose(T_base_tag[:3, 3], follow_cfg.standoff, follow_cfg.height_offset)
        q_seed, ok = ik(T_des, q_seed)
        if not ok:
            raise ConfigError(
                f"the follow pose for the tag at {T_base_tag[:3, 3].round(3)} m is out of reach: "
                "choose another center or radius (or follow.standoff / height_offset)"
            )


def _move_to(ctx: Any, q: Array) -> None:
    """A task: move the arm to joint positions ``q`` in 2 s."""
    from armvision.runtime.context import TaskError

    if not ctx.move_joints(q, moving_time=2.0):
        raise TaskError(f"the arm refused the start pose: {ctx.arm.last_error}")


def _run_mode(
    config: Config,
    seed: int,
    scene: Any,
    calibration: Any,
    path: Callable[[float], Array],
    lap: float,
    mode: str,
    duration_s: float,
    settle_s: float,
) -> dict[str, Any]:
    """One follow run in ``mode``; its task report and the errors against the truth."""
    from armvision.bench.system import sim_system, sim_world

    follow_cfg = config.follow
    tag_id = follow_cfg.tag_id
    sample_period = 1.0 / config.fusion.rate_hz
    samples: list[tuple[float, Array]] = []
    clock = {"t0": math.inf, "next": math.inf}

    system = sim_system(config, seed, scene=scene, calibration=calibration)
    world = sim_world(system)
    try:
        _check_path(config, world.T_base_cam(), system.camera.intrinsics, path, lap)
    except ConfigError:
        system.close()
        raise

    def move_tag(t: float) -> None:
        """Before every physics step: place the tag; on the sample grid, record the error."""
        elapsed = t - clock["t0"]
        T_base_tag = path(elapsed)
        world.set_loose_tag_pose(tag_id, T_base_tag)  # also brings the kinematics up to t
        if t >= clock["next"] - 1e-9 and elapsed <= duration_s + 1e-9:
            clock["next"] += sample_period
            p_des = desired_ee_pose(
                T_base_tag[:3, 3], follow_cfg.standoff, follow_cfg.height_offset
            )[:3, 3]
            samples.append((elapsed, world.T_base_ee()[:3, 3] - p_des))

    with system:
        world.add_controller(move_tag)
        T_start = desired_ee_pose(path(0.0)[:3, 3], follow_cfg.standoff, follow_cfg.height_offset)
        q_start, ok = ik(T_start, np.zeros(VX300S.dof))
        if not ok:
            raise RuntimeError("the start pose is out of reach (the path check should catch it)")
        # As a task, so the stages keep time with the world while the arm moves; the tag
        # stage is off meanwhile (nothing to measure yet, and it saves 60 renders).
        system.set_detector("tags", False)
        moved = system.run_task("start pose", _move_to, q=q_start)
        if moved.phase != "succeeded":
            raise RuntimeError(f"cannot reach the start pose: {moved.error}")
        system.set_detector("tags", True)
        system.pump(world.time + WARM_UP_S)
        clock["t0"] = clock["next"] = world.time
        status = system.run_task(
            "follow", follow, target="tag", tag_id=tag_id, duration_s=duration_s, mode=mode
        )
        world.remove_controller(move_tag)

    times = np.array([t for t, _ in samples])
    errors = np.array([e for _, e in samples]).reshape(-1, 3)
    scored = errors[times >= settle_s - 1e-9]
    norms = 1000.0 * np.linalg.norm(scored, axis=1)
    result = dict(status.result or {})
    tracked = result.get("tracked_s")
    return {
        "phase": status.phase,
        "error": status.error,
        "rms_error_mm": _rms_mm(scored),
        "max_error_mm": float(np.max(norms)) if len(norms) else math.nan,
        "median_error_mm": float(np.median(norms)) if len(norms) else math.nan,
        # The constant part (calibration, tag pose bias) and what moves with the target.
        "mean_error_mm": (1000.0 * scored.mean(axis=0)).tolist() if len(scored) else None,
        "rms_error_mm_about_mean": _rms_mm(scored - scored.mean(axis=0)),
        "samples": len(scored),
        "rate_hz": result.get("rate_hz"),
        "time_lost_s": None if tracked is None else max(duration_s - tracked, 0.0),
        "task": result,
    }


def _check_arguments(
    config: Config,
    duration: float,
    speed: float,
    radius: float,
    settle_s: float,
    modes: tuple[str, ...],
) -> None:
    """ConfigError for an argument of :func:`evaluate_follow` that makes no run."""
    for name, value in (
        ("duration_s", duration),
        ("speed", speed),
        ("radius", radius),
    ):
        if not (math.isfinite(value) and value > 0.0):
            raise ConfigError(f"{name} must be a positive number, not {value}")
    if not 0.0 <= settle_s < duration:
        raise ConfigError(f"settle_s must be in [0, duration_s = {duration}), not {settle_s}")
    unknown = [m for m in modes if m not in MODES]
    if unknown or not modes:
        raise ConfigError(f"modes must be some of {MODES}, not {modes}")
    if config.follow.tag_id == config.tag.id:
        raise ConfigError(
            f"follow.tag_id {config.follow.tag_id} is the gripper tag; choose another id"
        )


def _follow_scene(
    config: Config,
    seed: int,
    center: tuple[float, float],
    radius: float,
    speed: float,
) -> tuple[Any, Callable[[float], Array], float, float]:
    """The seed's scene with the loose tag at the start of its circle: (scene, path,
    start angle, direction)."""
    from armvision.sim.assets import tag_outer_size
    from armvision.sim.scene import LooseTag, footprint_of, generate_scene

    rng = np.random.default_rng([seed, 0xF011])
    phase = float(rng.uniform(-math.pi, math.pi))
    direction = float(rng.choice([-1.0, 1.0]))
    yaw = float(rng.uniform(-math.pi, math.pi))
    path = circle_path(center, radius, speed, phase, direction, yaw)
    start = path(0.0)[:3, 3]
    base_scene = generate_scene(config, seed)
    tag = LooseTag(config.follow.tag_id, float(start[0]), float(start[1]), yaw, config.tag.size)
    kept = base_scene.objects
    if config.sim.profile == "cluttered":
        # The tag slides on the table; a cluttered scene's objects stand so close that those
        # on its circle would hide it all the way round: they are left out, the rest stay
        # around it. (The default scenes are kept as they always were, for their figures.)
        clearance = tag_outer_size(config.tag.size) / math.sqrt(2.0) + PATH_CLEARANCE_M
        lap = np.linspace(0.0, 2.0 * math.pi * radius / speed, 72)
        on_path = [path(float(t))[:2, 3] for t in lap]
        kept = tuple(
            o
            for o in kept
            if min(footprint_of(o).distance_to_point(float(x), float(y)) for x, y in on_path)
            > clearance
        )
    scene = dataclasses.replace(base_scene, objects=kept, loose_tags=(tag,))
    return scene, path, phase, direction


def _summary(runs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    def pick(mode: str, key: str) -> Any:
        return runs[mode][key] if mode in runs else None

    return {
        "rms_error_mm_servo": pick("servo", "rms_error_mm"),
        "rms_error_mm_blocking": pick("blocking", "rms_error_mm"),
        "max_error_mm_servo": pick("servo", "max_error_mm"),
        "max_error_mm_blocking": pick("blocking", "max_error_mm"),
        "rate_hz_servo": pick("servo", "rate_hz"),
        "rate_hz_blocking": pick("blocking", "rate_hz"),
        "time_lost_s_servo": pick("servo", "time_lost_s"),
        "time_lost_s_blocking": pick("blocking", "time_lost_s"),
    }


def evaluate_follow(
    config: Config,
    seed: int = 0,
    duration_s: float | None = None,
    speed: float = 0.10,
    radius: float = 0.06,
    center: tuple[float, float] = (0.45, 0.0),
    settle_s: float = 2.0,
    calibration_error: tuple[float, float] | None = (0.002, 0.2),
    modes: tuple[str, ...] = MODES,
) -> dict[str, Any]:
    """Follow a tag moving on a circle, servo and blocking, vs the simulator (module docstring).

    ``summary``: ``rms_error_mm_servo`` and ``rms_error_mm_blocking`` (true ee vs the desired
    position for the true tag, RMS from ``settle_s`` to ``duration_s``), the max errors, the
    rates achieved (servo cycles and blocking moves per second) and the time each mode had
    lost the tag. ``modes`` holds each run's details and the task's own report. A mode left out
    of ``modes`` is reported as None.
    """
    from armvision.runtime.state import CalibrationStatus

    duration = config.follow.duration_s if duration_s is None else float(duration_s)
    _check_arguments(config, duration, speed, radius, settle_s, modes)
    config = dataclasses.replace(
        config,
        sim=dataclasses.replace(config.sim, min_objects=0, max_objects=0, loose_tags=0),
        runtime=dataclasses.replace(config.runtime, object_detection=False, liquid_detection=False),
    )
    scene, path, phase, direction = _follow_scene(config, seed, center, radius, speed)
    lap = 2.0 * math.pi * radius / speed

    T_true = np.asarray(scene.T_base_cam, dtype=float)
    if calibration_error is None:
        T_est, calibration_info = T_true, {"source": "simulator truth"}
    else:
        T_est, calibration_info = perturbed_calibration(T_true, seed, *calibration_error)
    calibration = CalibrationStatus(calibration_info["source"], "none", None, T_est)

    runs = {
        mode: _run_mode(config, seed, scene, calibration, path, lap, mode, duration, settle_s)
        for mode in modes
    }
    return {
        "seed": seed,
        "summary": _summary(runs),
        "path": {
            "center_m": list(center),
            "radius_m": radius,
            "speed_m_s": speed,
            "lap_s": lap,
            "start_angle_rad": phase,
            "direction": "counter-clockwise" if direction > 0 else "clockwise",
            "tag_id": config.follow.tag_id,
        },
        "duration_s": duration,
        "settle_s": settle_s,
        "error_definition": (
            "true ee position minus the desired position for the true tag pose (standoff "
            f"{config.follow.standoff} m, height offset {config.follow.height_offset} m), "
            f"every {1000.0 / config.fusion.rate_hz:.0f} ms of simulation time from settle_s "
            "to duration_s"
        ),
        "calibration": calibration_info,
        "modes": runs,
    }
