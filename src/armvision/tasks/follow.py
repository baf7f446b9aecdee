"""Follow a tag or a bottle with the end effector: a servo loop, or the paper's blocking loop.

**Where the end effector goes.** For a target at ``p`` (base frame) at horizontal distance d
from the base axis and bearing yaw = atan2(y, x), the end effector keeps ``follow.standoff``
back from it on the line from the base, ``follow.height_offset`` above it:

    p_ee = (d_ee cos yaw, d_ee sin yaw, z + height_offset),  d_ee = max(d - standoff, D_MIN_M)

and points at it: its x axis (the gripper's approach axis) along p - p_ee, no roll. With the
defaults (12 cm back, 10 cm up) the gripper looks down at the target at 40 degrees, from the
robot's side, so it never hides a target from a camera standing in front of the robot.
:func:`desired_ee_pose` is this rule; the follow evaluation scores against it.

**Servo mode** (default): every 1/``follow.rate_hz`` seconds (50 Hz; at least 30 Hz):

1. the newest target measurement goes into a :class:`~armvision.tasks.servo.TargetEstimator`
   (tag: ``state.T_base_cam @ T_cam_tag`` of the tag with ``tag_id`` in the newest processed
   frame, with the camera pose the system works with at that cycle, the calibration as the
   fusion loop refines it; bottle: the fusion loop's track, which has a velocity already);
2. the desired pose at the estimated current target position, and its rate of change for the
   estimated target velocity (the feed-forward twist);
3. a Cartesian command twist = feed-forward + ``follow.gain`` x pose error (position error and
   the rotation vector of R_des R^T), the linear part limited to ``follow.max_speed`` and
   ``follow.max_accel``, the angular part to :data:`~armvision.tasks.servo.MAX_ANGULAR_SPEED`
   and :data:`~armvision.tasks.servo.MAX_ANGULAR_ACCEL`;
4. damped least-squares differential IK on the ee-point Jacobian
   (:func:`~armvision.tasks.servo.servo_step`), qdot = W J^T (J W J^T + Lambda)^-1 V with W
   weighting each joint by its velocity limit and the damping ``follow.damping`` applied only
   to near-singular directions (singular value under
   :data:`~armvision.tasks.servo.DAMPING_THRESHOLD`; the follow poses are near the wrist
   singularity, the forearm-roll and wrist-rotate axes almost aligned); joints at a limit
   moving further out are locked, and qdot is scaled so no joint exceeds
   :data:`~armvision.tasks.servo.JOINT_SPEED_FRACTION` of its velocity limit;
5. ``ctx.stream(q + qdot dt)``.

The loop integrates its own commanded joint vector q (started from the encoders) and closes
the Cartesian loop on fk(q), not on the encoder readings: the servos track the commanded angle,
so this is free of encoder noise and of the encoders' zero offsets. The encoders are checked
every cycle so an arm that is not following the commands (blocked, torque off) stops the task
(:data:`DIVERGENCE_RAD`). At the end (duration, or target lost) the command velocity ramps down
at the acceleration limits before the task returns, so the arm stops smoothly.

**Blocking mode** (``mode="blocking"``, the paper's loop, for comparison): read the newest
target position, ``ctx.move_pose`` to the desired pose (Interbotix timing: ``moving_time``,
default the arm's 2 s, with ``position_priority``), wait for the move to end, repeat.

**Stopping.** After ``follow.duration_s`` (ok), or when the target has not been seen for
``follow.lost_timeout_s`` (ok False, reason "target lost: ..."); a target never seen within
that time after the start counts as lost too. Stop raises TaskStopped (the system halts the
arm and reports the task stopped). A target is "seen" at the capture time of the frame it
was detected in (tags) or its track's newest detection (bottles), and "not seen for" a time
when the frames its detector processed since cover that much camera time without it: a
machine too busy to process every frame does not lose a target that is in view. With no frame
processed at all for ``lost_timeout_s`` + :data:`NO_FRAMES_S` it is lost as well.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from armvision.config import FollowConfig
from armvision.geometry import make_T, rpy_to_R
from armvision.robot.base import STREAM_MAX_STEP_S
from armvision.robot.kinematics import ArmModel, fk
from armvision.runtime.context import TaskContext, TaskError
from armvision.runtime.state import SystemState
from armvision.tasks.servo import MAX_EXTRAPOLATION_S, ServoGains, TargetEstimator, servo_step

Array = NDArray[np.float64]

#: The end effector keeps at least this far from the base axis (the waist is singular on it).
D_MIN_M = 0.10
#: Commanded and measured joint angles this far apart (rad) mean the arm is not following.
DIVERGENCE_RAD = 0.25
#: The ramp-down at the end takes at most this long, s (max_speed / max_accel is 0.25 s).
RAMP_DOWN_MAX_S = 1.0
#: Progress is reported this often (clock seconds).
PROGRESS_EVERY_S = 1.0
#: With no frame processed by the target's detector for ``follow.lost_timeout_s`` plus this
#: long (seconds; the camera unplugged, the detector switched off), the target is lost.
NO_FRAMES_S = 1.0

Mode = Literal["servo", "blocking"]
TargetKind = Literal["tag", "bottle"]
StopCause = Literal["duration", "lost"]


# --------------------------------------------------------------------------- geometry


def desired_ee_pose(p_target: ArrayLike, standoff: float, height_offset: float) -> Array:
    """``T_base_ee`` for following a target at ``p_target`` (base frame; module docstring).

    ``standoff`` m back toward the base on the horizontal line from the base axis (never
    nearer than :data:`D_MIN_M` to that axis), ``height_offset`` m above the target, the
    gripper's x axis pointing at the target. Example: a target at (0.5, 0, 0) with 0.12 / 0.10
    gives the end effector at (0.38, 0, 0.10) pitched down atan(0.10 / 0.12) = 39.8 degrees.
    """
    p = np.asarray(p_target, dtype=float)
    d = math.hypot(p[0], p[1])
    yaw = math.atan2(p[1], p[0]) if d > 1e-9 else 0.0
    d_ee = max(d - standoff, D_MIN_M)
    p_ee = np.array([d_ee * math.cos(yaw), d_ee * math.sin(yaw), p[2] + height_offset])
    horizontal = d - d_ee  # along the bearing, toward the target (negative: it is behind)
    pitch = math.atan2(height_offset, horizontal)  # positive pitch points the gripper down
    return make_T(rpy_to_R(0.0, pitch, yaw), p_ee)


def pose_twist(T_from: Array, T_to: Array, dt: float) -> Array:
    """The constant twist (omega, p_dot) taking ``T_from`` to ``T_to`` in ``dt``: the rotation
    vector of R_to R_from^T (space frame) and the displacement of the origin, over ``dt``."""
    w = Rotation.from_matrix(T_to[:3, :3] @ T_from[:3, :3].T).as_rotvec()
    return np.concatenate([w, T_to[:3, 3] - T_from[:3, 3]]) / dt


def desired_pose_and_twist(
    p_target: ArrayLike, v_target: ArrayLike, standoff: float, height_offset: float
) -> tuple[Array, Array]:
    """:func:`desired_ee_pose` at ``p_target`` and its rate of change (omega, p_dot) for a
    target moving at ``v_target`` m/s, by a central difference over +-5 ms."""
    p, v = np.asarray(p_target, dtype=float), np.asarray(v_target, dtype=float)
    T_des = desired_ee_pose(p, standoff, height_offset)
    if not np.any(v):
        return T_des, np.zeros(6)
    h = 0.005
    before = desired_ee_pose(p - v * h, standoff, height_offset)
    after = desired_ee_pose(p + v * h, standoff, height_offset)
    return T_des, pose_twist(before, after, 2.0 * h)


# --------------------------------------------------------------------------- the target


class _TagTarget:
    """A tag other than the gripper's, from the tag stage's newest processed frame, mapped
    into the base frame with the camera pose of the state it is polled with
    (``state.T_base_cam``: the calibration as the fusion loop refines it)."""

    def __init__(self, tag_id: int) -> None:
        self.tag_id = tag_id
        self.estimator = TargetEstimator()
        self._frame_time: float | None = None

    @property
    def label(self) -> str:
        return f"tag {self.tag_id}"

    @property
    def last_seen(self) -> float | None:
        return self.estimator.last_time

    @property
    def last_looked(self) -> float | None:
        """The time of the newest frame the tag stage processed."""
        return self._frame_time

    def poll(self, state: SystemState) -> None:
        t = state.tags_time
        if t is None or (self._frame_time is not None and t <= self._frame_time):
            return
        self._frame_time = t
        for tag in state.tags:
            if tag.id == self.tag_id:
                self.estimator.update(t, (state.T_base_cam @ tag.T_cam_tag)[:3, 3])
                return

    def estimate(self, t: float) -> tuple[Array, Array] | None:
        return self.estimator.estimate(t)

    def newest(self) -> Array | None:
        return self.estimator.last_position

    @property
    def measurements(self) -> int:
        return self.estimator.count


class _TrackTarget:
    """A bottle's confirmed track from the fusion loop (position and velocity already filtered).

    Without ``track_id`` the first bottle seen (nearest the base) is taken and kept.
    """

    def __init__(self, track_id: int | None) -> None:
        self.track_id = track_id
        self.last_seen: float | None = None
        #: The time of the newest frame the object stage processed.
        self.last_looked: float | None = None
        self.measurements = 0
        self._p: Array | None = None
        self._v = np.zeros(3)
        self._t = 0.0

    @property
    def label(self) -> str:
        return "a bottle" if self.track_id is None else f"bottle track {self.track_id}"

    def poll(self, state: SystemState) -> None:
        if state.detections_frame is not None:
            self.last_looked = float(state.detections_frame.timestamp)
        if self.track_id is None:
            bottles = state.bottles()
            if not bottles:
                return
            self.track_id = bottles[0].id
        track = state.track(self.track_id)
        if track is None or (self.last_seen is not None and track.last_seen <= self.last_seen):
            return
        self.last_seen = float(track.last_seen)
        self.measurements += 1
        self._p = np.array(track.p_base, dtype=float)
        self._v = np.array(track.v_base, dtype=float)
        self._t = float(track.t)

    def estimate(self, t: float) -> tuple[Array, Array] | None:
        if self._p is None or self.last_seen is None:
            return None
        horizon = self.last_seen + MAX_EXTRAPOLATION_S
        v = self._v if t <= horizon else np.zeros(3)
        return self._p + self._v * (min(t, horizon) - self._t), v

    def newest(self) -> Array | None:
        if self._p is None or self.last_seen is None:
            return None
        return self._p + self._v * (self.last_seen - self._t)


# --------------------------------------------------------------------------- the result


@dataclass(frozen=True)
class FollowResult:
    """What a follow did. ``ok`` unless the target was lost.

    ``mode`` servo or blocking; ``target`` what was followed ("tag 0", "bottle track 3");
    ``stop_cause`` duration or lost (Stop raises TaskStopped instead); ``duration_s`` from
    start to standstill; ``stopped_at`` the clock time the loop decided to stop and
    ``last_seen`` the target's last sighting (clock seconds, None if never); ``cycles`` servo
    cycles (or blocking moves) and ``rate_hz`` their rate over the loop's time; ``overruns``
    cycles that started more than a period late; ``tracked_s`` the loop time during which the
    target had been seen within :data:`MAX_EXTRAPOLATION_S`; ``measurements`` target
    sightings; ``latency_ms_*`` how old the newest target measurement was when a command went
    out (clock ms); ``compute_ms_*`` wall-clock time of a cycle's own work; ``limited_cycles``
    cycles in which a Cartesian speed or acceleration limit bit; ``failed_moves`` blocking
    moves the arm refused; ``error_mm_*`` the loop's own view of its tracking error: fk of the
    (calibrated) encoders vs the desired position for the estimated target, every cycle.
    """

    ok: bool
    reason: str
    mode: Mode
    target: str
    stop_cause: StopCause
    duration_s: float
    stopped_at: float
    last_seen: float | None
    cycles: int
    rate_hz: float
    overruns: int
    tracked_s: float
    measurements: int
    latency_ms_mean: float | None
    latency_ms_max: float | None
    compute_ms_mean: float | None
    compute_ms_max: float | None
    limited_cycles: int
    failed_moves: int
    error_mm_rms: float | None
    error_mm_max: float | None

    def to_dict(self) -> dict[str, Any]:
        def r(x: float | None, n: int = 3) -> float | None:
            return None if x is None else round(float(x), n)

        return {
            "ok": self.ok,
            "reason": self.reason,
            "mode": self.mode,
            "target": self.target,
            "stop_cause": self.stop_cause,
            "duration_s": r(self.duration_s),
            "stopped_at": r(self.stopped_at, 4),
            "last_seen": r(self.last_seen, 4),
            "cycles": self.cycles,
            "rate_hz": r(self.rate_hz, 2),
            "overruns": self.overruns,
            "tracked_s": r(self.tracked_s),
            "measurements": self.measurements,
            "latency_ms_mean": r(self.latency_ms_mean, 2),
            "latency_ms_max": r(self.latency_ms_max, 2),
            "compute_ms_mean": r(self.compute_ms_mean, 3),
            "compute_ms_max": r(self.compute_ms_max, 3),
            "limited_cycles": self.limited_cycles,
            "failed_moves": self.failed_moves,
            "error_mm_rms": r(self.error_mm_rms, 2),
            "error_mm_max": r(self.error_mm_max, 2),
        }


class _Stats:
    """Counters a loop fills in, turned into a :class:`FollowResult` at the end."""

    def __init__(self, start: float) -> None:
        self.start = start
        self.cycles = 0
        self.overruns = 0
        self.tracked_s = 0.0
        self.latency: list[float] = []
        self.compute: list[float] = []
        self.errors: list[float] = []
        self.limited = 0
        self.failed_moves = 0

    def result(
        self,
        mode: Mode,
        target: Any,
        cause: StopCause,
        reason: str,
        stopped_at: float,
        end: float,
    ) -> FollowResult:
        def mean(x: list[float], scale: float = 1.0) -> float | None:
            return scale * float(np.mean(x)) if x else None

        def peak(x: list[float], scale: float = 1.0) -> float | None:
            return scale * float(np.max(x)) if x else None

        loop_time = stopped_at - self.start
        errors = np.array(self.errors)
        return FollowResult(
            ok=cause == "duration",
            reason=reason,
            mode=mode,
            target=target.label,
            stop_cause=cause,
            duration_s=end - self.start,
            stopped_at=stopped_at,
            last_seen=target.last_seen,
            cycles=self.cycles,
            rate_hz=self.cycles / loop_time if loop_time > 0 else 0.0,
            overruns=self.overruns,
            tracked_s=self.tracked_s,
            measurements=target.measurements,
            latency_ms_mean=mean(self.latency, 1e3),
            latency_ms_max=peak(self.latency, 1e3),
            compute_ms_mean=mean(self.compute, 1e3),
            compute_ms_max=peak(self.compute, 1e3),
            limited_cycles=self.limited,
            failed_moves=self.failed_moves,
            error_mm_rms=1e3 * math.sqrt(float(np.mean(errors**2))) if len(errors) else None,
            error_mm_max=1e3 * float(np.max(errors)) if len(errors) else None,
        )


# --------------------------------------------------------------------------- the task


def follow(
    ctx: TaskContext,
    target: TargetKind = "tag",
    tag_id: int | None = None,
    track_id: int | None = None,
    duration_s: float | None = None,
    mode: Mode = "servo",
    moving_time: float | None = None,
) -> FollowResult:
    """Follow a tag (``tag_id``, default ``follow.tag_id``) or a bottle (``track_id``, default
    the nearest) for ``duration_s`` (default ``follow.duration_s``); see the module docstring.

    ``mode``: "servo" (the streaming loop at ``follow.rate_hz``) or "blocking" (the paper's
    move-and-wait loop, each move taking ``moving_time`` s, default the arm's). Returns a
    :class:`FollowResult`; raises TaskError for bad arguments or an arm that does not follow.
    """
    config = ctx.config.follow
    if target not in ("tag", "bottle"):
        raise TaskError(f"follow target must be 'tag' or 'bottle', not {target!r}")
    if mode not in ("servo", "blocking"):
        raise TaskError(f"follow mode must be 'servo' or 'blocking', not {mode!r}")
    duration = config.duration_s if duration_s is None else float(duration_s)
    if not (math.isfinite(duration) and duration > 0.0):
        raise TaskError(f"follow duration must be a positive number of seconds, not {duration_s}")
    if moving_time is not None and not (math.isfinite(moving_time) and moving_time > 0.0):
        raise TaskError(f"moving_time must be a positive number of seconds, not {moving_time}")
    ctx.require_aim()
    source: _TagTarget | _TrackTarget
    if target == "tag":
        tag = config.tag_id if tag_id is None else int(tag_id)
        if tag == ctx.config.tag.id:
            raise TaskError(
                f"tag {tag} is the gripper's own tag; follow another tag "
                "(set follow.tag_id or pass tag_id)"
            )
        source = _TagTarget(tag)
    else:
        source = _TrackTarget(track_id)
    ctx.progress(0.0, f"following {source.label} for {duration:.1f} s ({mode})")
    if mode == "servo":
        return _servo(ctx, config, source, duration)
    return _blocking(ctx, config, source, duration, moving_time)


def _ended(
    source: Any, now: float, start: float, duration: float, timeout: float
) -> tuple[StopCause, str] | None:
    """Whether a follow ends at ``now`` (its duration done, or the target lost), and why."""
    if now - start >= duration:
        return "duration", f"followed {source.label} for {duration:.1f} s"
    lost = _lost_reason(source, now, start, timeout)
    return None if lost is None else ("lost", lost)


def _lost_reason(source: Any, now: float, start: float, timeout: float) -> str | None:
    """Why the target counts as lost at ``now``, or None if it does not.

    Lost when the frames its detector processed after it was last seen (after the start, if it
    never was) cover more than ``timeout`` of camera time without it: on a busy machine frames
    come late and fewer, which is not the target going out of view. Lost too when the detector
    processed no frame at all for ``timeout`` + NO_FRAMES_S (the camera or detector stopped).
    """
    seen, looked = source.last_seen, source.last_looked
    since = start if seen is None else seen
    if looked is not None and looked - since > timeout:
        if seen is None:
            return (
                f"target lost: {source.label} not seen in the first {timeout:.2f} s "
                "(is it in view of the camera, and its detector on?)"
            )
        return f"target lost: {source.label} not seen for {now - seen:.2f} s"
    newest = since if looked is None else max(since, looked)
    if now - newest > timeout + NO_FRAMES_S:
        return (
            f"target lost: no frame processed for {now - newest:.2f} s while following "
            f"{source.label} (is the camera running, and its detector on?)"
        )
    return None


def _encoder_error(ctx: TaskContext, model: ArmModel, p_des: Array) -> tuple[Array, float]:
    """The calibrated encoder reading and its ee's distance from ``p_des`` (m)."""
    q_meas = ctx.joint_positions()
    return q_meas, float(np.linalg.norm(fk(q_meas, model)[:3, 3] - p_des))


def _servo(ctx: TaskContext, config: FollowConfig, source: Any, duration: float) -> FollowResult:
    arm = ctx.arm
    model = arm.model
    gains = ServoGains.from_config(config)
    period = 1.0 / config.rate_hz
    start = ctx.now()
    stats = _Stats(start)
    q_cmd = ctx.joint_positions()
    twist = np.zeros(6)
    last_command: float | None = None
    next_tick = start
    next_progress = start + PROGRESS_EVERY_S
    cause: StopCause = "duration"
    reason = ""
    while True:
        now = ctx.now()
        wall = time.perf_counter()
        source.poll(ctx.state())
        ended = _ended(source, now, start, duration, config.lost_timeout_s)
        if ended is not None:
            cause, reason = ended
            break
        estimate = source.estimate(now)
        if estimate is not None:
            # The arm checks each target's step against the time since its previous one; its
            # clock moves on while we compute (a realtime simulation or a busy machine), so
            # time the step from just after the previous target went to just before this one
            # goes: never longer than the arm's interval.
            now_cmd = ctx.now()
            dt = (
                period
                if last_command is None
                else min(max(now_cmd - last_command, 1e-3), STREAM_MAX_STEP_S)
            )
            T_des, twist_ff = desired_pose_and_twist(
                estimate[0], estimate[1], config.standoff, config.height_offset
            )
            step = servo_step(q_cmd, T_des, twist_ff, twist, dt, gains, model)
            q_meas, error = _encoder_error(ctx, model, T_des[:3, 3])
            _check_following(q_cmd, q_meas, model)
            if not ctx.stream(step.q):
                raise TaskError(
                    f"the arm refused a servo target: {arm.last_error} (the follow stopped)"
                )
            q_cmd, twist, last_command = step.q, step.command, ctx.now()
            stats.cycles += 1
            stats.limited += step.cartesian_limited
            stats.errors.append(error)
            stats.latency.append(now - source.last_seen)
            if now - source.last_seen <= MAX_EXTRAPOLATION_S:
                stats.tracked_s += dt
            stats.compute.append(time.perf_counter() - wall)
        if now >= next_progress:
            ctx.progress((now - start) / duration, f"following {source.label}")
            next_progress += PROGRESS_EVERY_S
        next_tick += period
        if next_tick < ctx.now() - period:  # more than a cycle behind: do not catch up
            stats.overruns += 1
            next_tick = ctx.now()
        ctx.sleep(next_tick - ctx.now())
    stopped_at = ctx.now()
    _ramp_down(ctx, q_cmd, twist, last_command, period, gains, model)
    return stats.result("servo", source, cause, reason, stopped_at, ctx.now())


def _check_following(q_cmd: Array, q_meas: Array, model: ArmModel) -> None:
    gap = np.abs(q_meas - q_cmd)
    j = int(np.argmax(gap))
    if gap[j] > DIVERGENCE_RAD:
        raise TaskError(
            f"the arm is not following the servo targets: {model.joint_names[j]} is "
            f"{math.degrees(gap[j]):.0f} degrees from its command (blocked, or torque off?); "
            "the follow stopped"
        )


def _ramp_down(
    ctx: TaskContext,
    q_cmd: Array,
    twist: Array,
    last_command: float | None,
    period: float,
    gains: ServoGains,
    model: ArmModel,
) -> None:
    """Bring the commanded motion to rest at the acceleration limits, streaming as it goes."""
    end = ctx.now() + RAMP_DOWN_MAX_S
    while np.linalg.norm(twist[3:]) > 1e-4 or np.linalg.norm(twist[:3]) > 1e-3:
        now = ctx.now()
        if now >= end or last_command is None:
            break
        dt = min(max(now - last_command, 1e-3), STREAM_MAX_STEP_S)
        # Aim where the command is: zero error and no feed-forward, so only the limiter acts.
        step = servo_step(q_cmd, fk(q_cmd, model), np.zeros(6), twist, dt, gains, model)
        if not ctx.stream(step.q):
            break  # the arm holds its last accepted target
        q_cmd, twist, last_command = step.q, step.command, now
        ctx.sleep(period)


def _blocking(
    ctx: TaskContext,
    config: FollowConfig,
    source: Any,
    duration: float,
    moving_time: float | None,
) -> FollowResult:
    model = ctx.arm.model
    period = 1.0 / config.rate_hz
    start = ctx.now()
    stats = _Stats(start)
    cause: StopCause = "duration"
    reason = ""
    while True:
        now = ctx.now()
        source.poll(ctx.state())
        ended = _ended(source, now, start, duration, config.lost_timeout_s)
        if ended is not None:
            cause, reason = ended
            break
        p_target = source.newest()
        if p_target is None:
            ctx.sleep(period)
            continue
        wall = time.perf_counter()
        fresh = now - source.last_seen <= MAX_EXTRAPOLATION_S
        T_des = desired_ee_pose(p_target, config.standoff, config.height_offset)
        _, error = _encoder_error(ctx, model, T_des[:3, 3])
        stats.errors.append(error)
        stats.latency.append(now - source.last_seen)
        stats.compute.append(time.perf_counter() - wall)
        stats.cycles += 1
        ctx.progress((now - start) / duration, f"moving toward {source.label}")
        if not ctx.move_pose(T_des, moving_time=moving_time, position_priority=True):
            stats.failed_moves += 1
            ctx.sleep(period)
        if fresh:
            stats.tracked_s += ctx.now() - now
    stopped_at = ctx.now()
    return stats.result("blocking", source, cause, reason, stopped_at, stopped_at)
