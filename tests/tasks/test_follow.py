"""Following a tag: the servo math against fk, its limits, and the task in the lockstep sim."""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from armvision.bench.system import sim_system
from armvision.config import Config
from armvision.errors import ConfigError
from armvision.eval.follow import evaluate_follow
from armvision.geometry import make_T
from armvision.robot.kinematics import VX300S, fk
from armvision.tasks.follow import (
    NO_FRAMES_S,
    _lost_reason,
    _TagTarget,
    desired_ee_pose,
    desired_pose_and_twist,
    follow,
)
from armvision.tasks.servo import ServoGains, TargetEstimator, damped_least_squares, servo_step

#: A comfortable arm pose in front of the robot, away from limits and singularities.
Q_MID = np.array([0.3, -0.4, 0.5, 0.2, 0.7, -0.1])


# --------------------------------------------------------------------------- pure math


def test_desired_pose_stands_off_toward_the_base_and_points_at_the_target() -> None:
    T = desired_ee_pose([0.5, 0.0, 0.0], standoff=0.12, height_offset=0.10)
    assert np.allclose(T[:3, 3], [0.38, 0.0, 0.10])
    pointing = np.array([0.12, 0.0, -0.10]) / math.hypot(0.12, 0.10)
    assert np.allclose(T[:3, 0], pointing)  # the gripper's x axis looks at the target
    assert abs(T[2, 1]) < 1e-12  # no roll: the fingers' y axis stays horizontal
    # At a bearing of 90 degrees the same rule, turned: the stand-off is along the line
    # from the base axis, the height above the target's own height.
    T = desired_ee_pose([0.0, 0.5, 0.05], standoff=0.12, height_offset=0.10)
    assert np.allclose(T[:3, 3], [0.0, 0.38, 0.15])
    assert np.allclose(T[:3, 0], [0.0, 0.12 / math.hypot(0.12, 0.1), -0.1 / math.hypot(0.12, 0.1)])


def test_feed_forward_twist_is_the_rate_of_change_of_the_desired_pose() -> None:
    # A target moving straight away from the base: the ee moves the same way, does not turn.
    _, twist = desired_pose_and_twist([0.5, 0.0, 0.0], [0.1, 0.0, 0.0], 0.12, 0.10)
    assert np.allclose(twist, [0, 0, 0, 0.1, 0, 0], atol=1e-9)
    # Moving sideways at (0.5, 0): the bearing turns at v / d = 0.2 rad/s about z and the ee,
    # at 0.38 m from the axis, moves at 0.2 x 0.38 = 0.076 m/s along y.
    _, twist = desired_pose_and_twist([0.5, 0.0, 0.0], [0.0, 0.1, 0.0], 0.12, 0.10)
    assert np.allclose(twist, [0, 0, 0.2, 0, 0.076, 0], atol=1e-6)


def test_damped_least_squares_by_hand() -> None:
    V = np.array([1.0, -2.0, 0.5])
    assert np.allclose(damped_least_squares(np.eye(3), V, 0.0), V)
    # J = 2 I: qdot = 2 / (4 + lambda^2) V.
    assert np.allclose(damped_least_squares(2.0 * np.eye(3), V, 0.5), 2.0 / 4.25 * V)
    # A joint with twice the weight takes twice the motion of a redundant pair.
    qdot = damped_least_squares(np.array([[1.0, 1.0]]), [3.0], 0.0, weights=[2.0, 1.0])
    assert np.allclose(qdot, [2.0, 1.0])


def test_servo_step_moves_the_ee_as_commanded() -> None:
    # Target 1 mm ahead along x, same orientation: gain 4 asks for 4 mm/s along x, which in
    # 20 ms is 0.08 mm along x; nothing else moves (tiny damping, no limit bites).
    T_now = fk(Q_MID)
    T_des = T_now.copy()
    T_des[0, 3] += 0.001
    gains = ServoGains(gain=4.0, damping=1e-4)
    step = servo_step(Q_MID, T_des, np.zeros(6), np.zeros(6), 0.02, gains)
    assert np.allclose(step.command, [0, 0, 0, 0.004, 0, 0])
    T_next = fk(step.q)
    assert np.allclose(T_next[:3, 3] - T_now[:3, 3], [8e-5, 0, 0], atol=1e-8)
    assert np.allclose(T_next[:3, :3], T_now[:3, :3], atol=1e-7)
    assert not step.cartesian_limited and not step.joint_limited


def test_servo_steps_respect_speed_acceleration_and_joint_limits() -> None:
    gains = ServoGains(max_speed=0.25, max_accel=1.0)
    dt = 0.02
    T_far = make_T(fk(Q_MID)[:3, :3], fk(Q_MID)[:3, 3] + [0.1, -0.25, 0.1])
    q, twist, positions, qs = Q_MID.copy(), np.zeros(6), [fk(Q_MID)[:3, 3]], [Q_MID]
    for _ in range(150):  # 3 s: speeds up, cruises, slows down on arrival
        step = servo_step(q, T_far, np.zeros(6), twist, dt, gains)
        q, twist = step.q, step.command
        positions.append(fk(q)[:3, 3])
        qs.append(q)
    v = np.diff(positions, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    speed = np.linalg.norm(v, axis=1)
    assert speed.max() > 0.9 * gains.max_speed  # the limit was reached, so it was tested
    assert speed.max() <= gains.max_speed * 1.01
    assert np.linalg.norm(a, axis=1).max() <= gains.max_accel * 1.05
    joint_speed = np.abs(np.diff(qs, axis=0)) / dt
    assert np.all(joint_speed <= gains.joint_speed_fraction * VX300S.velocity + 1e-9)
    assert np.linalg.norm(positions[-1] - T_far[:3, 3]) < 1e-3  # and it got there


def test_a_joint_at_its_limit_is_not_pushed_further() -> None:
    j = 2  # elbow
    q = Q_MID.copy()
    q[j] = VX300S.upper[j] - 0.005
    beyond = q.copy()
    beyond[j] += 0.1
    step = servo_step(q, fk(beyond), np.zeros(6), np.zeros(6), 0.02, ServoGains())
    assert step.joint_limited
    assert step.qdot[j] == 0.0
    assert VX300S.within_limits(step.q)


def test_estimator_follows_a_circle() -> None:
    # A point going round a 6 cm circle at 10 cm/s, seen at 30 Hz with 0.5 mm of noise.
    rng = np.random.default_rng(1)
    rho, v, f = 0.06, 0.10, 30.0
    w = v / rho

    def at(t: float) -> tuple[np.ndarray, np.ndarray]:
        p = np.array([0.45 + rho * math.cos(w * t), rho * math.sin(w * t), 0.0])
        return p, np.array([-v * math.sin(w * t), v * math.cos(w * t), 0.0])

    est = TargetEstimator()
    assert est.estimate(0.0) is None
    times = np.arange(0.0, 2.0, 1.0 / f)
    for t in times:
        est.update(float(t), at(float(t))[0] + rng.normal(0.0, 0.0005, 3))
    t_now = float(times[-1]) + 0.02
    p, vel = est.estimate(t_now)
    p_true, v_true = at(t_now)
    assert np.linalg.norm(p - p_true) < 0.001
    assert np.linalg.norm(vel - v_true) < 0.01  # 10 % of the speed, direction within 6 deg
    # Beyond the extrapolation horizon: held where the horizon put it, no velocity; the
    # quadratic extrapolation is still near the circle there (0.2 s ahead, noise amplified).
    horizon = float(times[-1]) + est.max_extrapolation_s
    p_late, v_late = est.estimate(t_now + 1.0)
    assert np.allclose(v_late, 0.0)
    assert np.allclose(p_late, est.estimate(horizon)[0])
    assert np.linalg.norm(p_late - at(horizon)[0]) < 0.005
    # Too few measurements for a velocity: the newest measurement, standing still.
    one = TargetEstimator()
    one.update(1.0, [0.4, 0.0, 0.0])
    p1, v1 = one.estimate(1.05)
    assert np.allclose(p1, [0.4, 0.0, 0.0]) and np.allclose(v1, 0.0)


def test_a_tag_is_mapped_with_the_camera_pose_of_each_state() -> None:
    # The fusion loop refines the camera pose as it runs: each sighting is mapped into the
    # base frame with the pose of the state it came in, not one taken at the start.
    tag = SimpleNamespace(id=3, T_cam_tag=make_T(p=[0.0, 0.0, 0.5]))
    source = _TagTarget(3)
    for t, x_cam in ((1.0, 0.4), (1.1, 0.41)):
        source.poll(SimpleNamespace(tags_time=t, tags=[tag], T_base_cam=make_T(p=[x_cam, 0, 0])))
        assert np.allclose(source.newest(), [x_cam, 0.0, 0.5])
    assert source.measurements == 2


# --------------------------------------------------------------------------- lockstep sim


def _tag_scene(config: Config, seed: int, tag_id: int, xy: tuple[float, float]):
    from armvision.sim.scene import LooseTag, generate_scene

    scene = generate_scene(config, seed)
    return dataclasses.replace(
        scene, loose_tags=(LooseTag(tag_id, xy[0], xy[1], 0.0, config.tag.size),)
    )


def _config() -> Config:
    config = Config()
    return dataclasses.replace(
        config,
        sim=dataclasses.replace(config.sim, min_objects=0, max_objects=0),
        runtime=dataclasses.replace(config.runtime, object_detection=False, liquid_detection=False),
    )


def test_a_loose_tag_goes_where_it_is_put() -> None:
    from armvision.errors import SimulationError
    from armvision.geometry import pose_error, rot_z
    from armvision.sim.world import SimWorld

    config = _config()
    world = SimWorld(config, 3, scene=_tag_scene(config, 3, 7, (0.4, 0.0)))
    T_target = make_T(rot_z(0.4) @ np.diag([1.0, -1.0, -1.0]), [0.47, -0.08, 0.001])
    world.set_loose_tag_pose(7, T_target)
    dp, dr = pose_error(world.T_base_loose_tags()[7], T_target)
    assert dp < 1e-9 and dr < 1e-9
    world.advance(0.1)  # a mocap body: physics leaves it there
    dp, _ = pose_error(world.T_base_loose_tags()[7], T_target)
    assert dp < 1e-9
    with pytest.raises(SimulationError, match="no loose tag 3"):
        world.set_loose_tag_pose(3, T_target)
    with pytest.raises(SimulationError, match="4x4"):
        world.set_loose_tag_pose(7, np.eye(3))


def test_a_target_is_lost_by_the_frames_looked_at_not_by_the_clock_alone() -> None:
    """Hand-worked: start at 10 s, timeout 0.5 s. On a busy machine the frames come late: the
    tag seen in the frame of 11.0 s, the newest frame processed from 11.3 s, at 11.8 s."""

    def target(seen, looked):
        return SimpleNamespace(label="tag 3", last_seen=seen, last_looked=looked)

    start, timeout = 10.0, 0.5
    # 0.8 s since it was seen, but the frames looked at since cover 0.3 s: not lost.
    assert _lost_reason(target(11.0, 11.3), 11.8, start, timeout) is None
    # Frames covering 0.6 s after it without it: lost, saying for how long on the clock.
    assert _lost_reason(target(11.0, 11.6), 11.8, start, timeout) == (
        "target lost: tag 3 not seen for 0.80 s"
    )
    # Never seen: frames covering more than the timeout after the start.
    assert _lost_reason(target(None, 10.4), 10.9, start, timeout) is None
    assert "not seen in the first 0.50 s" in _lost_reason(target(None, 10.6), 10.9, start, timeout)
    # No frame processed at all (camera unplugged): lost once timeout + NO_FRAMES_S pass.
    late = 11.0 + timeout + NO_FRAMES_S
    assert _lost_reason(target(11.0, 11.0), late - 0.01, start, timeout) is None
    reason = _lost_reason(target(11.0, 11.0), late + 0.01, start, timeout)
    assert reason.startswith("target lost: no frame processed for 1.51 s")
    assert _lost_reason(target(None, None), 10.0 + timeout + NO_FRAMES_S + 0.01, start, timeout)


def test_servo_stops_smoothly_with_target_lost_half_a_second_after_the_tag_goes() -> None:
    """From the sleep pose to a tag on the table, which is then hidden under the table top."""
    config = _config()
    tag_id, xy = config.follow.tag_id, (0.42, 0.05)
    system = sim_system(config, seed=3, scene=_tag_scene(config, 3, tag_id, xy))
    world = system.world
    T_tag = world.T_base_loose_tags()[tag_id]
    T_hidden = make_T(T_tag[:3, :3], [xy[0], xy[1], -0.2])  # inside the table: out of view
    hide_at = 3.0  # s after the follow starts; the arm has arrived by then
    clock = {"t0": math.inf}

    def hide(t: float) -> None:
        if t - clock["t0"] >= hide_at and "hidden" not in clock:
            world.set_loose_tag_pose(tag_id, T_hidden)
            clock["hidden"] = t

    streamed: list[tuple[float, np.ndarray]] = []
    stream = system.arm.stream_joint_targets

    def recording(q):
        ok = stream(q)
        if ok:
            streamed.append((world.time, np.array(q, dtype=float)))
        return ok

    system.arm.stream_joint_targets = recording  # type: ignore[method-assign]
    with system:
        world.add_controller(hide)
        system.pump(world.time + 0.3)
        clock["t0"] = world.time
        status = system.run_task("follow", follow, target="tag", duration_s=10.0)
        T_ee_final = world.T_base_ee()

    result = status.result
    assert status.phase == "failed" and status.error.startswith("target lost")
    assert result["stop_cause"] == "lost" and not result["ok"]
    period, frame = 1.0 / config.follow.rate_hz, 1.0 / config.camera.fps
    timeout = config.follow.lost_timeout_s
    hidden = clock["hidden"]
    assert hidden - frame <= result["last_seen"] <= hidden  # the last frame before it went
    assert result["stopped_at"] - result["last_seen"] > timeout
    # Within the timeout plus one cycle of the tag going; a lockstep cycle can start up to half
    # a frame late (a camera read in the system's pump advances to the camera's frame grid).
    assert result["stopped_at"] - hidden <= timeout + period + 0.5 * frame + 1e-6
    assert result["rate_hz"] >= 30.0
    # Before it went, the arm was where the rule puts it (sleep pose to there in 3 s).
    p_des = desired_ee_pose(T_tag[:3, 3], config.follow.standoff, config.follow.height_offset)
    assert np.linalg.norm(T_ee_final[:3, 3] - p_des[:3, 3]) < 0.02
    # Every streamed target, from the sleep pose through the ramp-down, within the limits.
    t = np.array([s[0] for s in streamed])
    p = np.array([fk(s[1])[:3, 3] for s in streamed])
    dt = np.diff(t)
    assert abs(np.mean(dt) - period) < 1e-3  # 50 Hz on average; each cycle late as above
    assert np.all(dt <= period + 0.5 * frame + 0.0021)
    gains = config.follow
    v = np.diff(p, axis=0) / dt[:, None]
    assert np.linalg.norm(v, axis=1).max() <= gains.max_speed * 1.02
    assert np.linalg.norm(v, axis=1).max() > 0.9 * gains.max_speed  # the long move hit it
    assert np.linalg.norm(v[-1]) < 0.005  # ramped down to rest
    # Acceleration on an even 40 ms grid: differences over the uneven lockstep intervals
    # (6-34 ms) would turn the ee path's curvature between joint-space steps into spurious
    # accelerations.
    grid = np.arange(t[0], t[-1], 0.04)
    p_grid = np.column_stack([np.interp(grid, t, p[:, k]) for k in range(3)])
    a = np.diff(p_grid, n=2, axis=0) / 0.04**2
    assert np.linalg.norm(a, axis=1).max() <= gains.max_accel * 1.05


def test_stop_ends_the_follow_at_once() -> None:
    config = _config()
    tag_id = config.follow.tag_id
    system = sim_system(config, seed=3, scene=_tag_scene(config, 3, tag_id, (0.42, 0.05)))
    world = system.world
    stop_at = {"t": math.inf}

    def press_stop(t: float) -> None:
        if t >= stop_at["t"]:
            stop_at["t"] = math.inf
            system.stop_task()

    with system:
        world.add_controller(press_stop)
        stop_at["t"] = world.time + 1.0
        start = world.time
        status = system.run_task("follow", follow, target="tag", duration_s=10.0)
    assert status.phase == "stopped"
    assert status.finished - start < 1.1


def test_eval_follow_short_run_servo_tracks_and_blocking_runs() -> None:
    result = evaluate_follow(Config(), seed=0, duration_s=4.0, settle_s=1.5)
    summary = result["summary"]
    for key in (
        "rms_error_mm_servo",
        "rms_error_mm_blocking",
        "max_error_mm_servo",
        "max_error_mm_blocking",
        "rate_hz_servo",
        "rate_hz_blocking",
        "time_lost_s_servo",
        "time_lost_s_blocking",
    ):
        assert key in summary
    assert summary["rms_error_mm_servo"] <= 20.0
    assert summary["rate_hz_servo"] >= 30.0
    assert summary["time_lost_s_servo"] == pytest.approx(0.0, abs=0.05)
    servo, blocking = result["modes"]["servo"], result["modes"]["blocking"]
    assert servo["phase"] == "succeeded" and blocking["phase"] == "succeeded"
    assert servo["samples"] == pytest.approx((4.0 - 1.5) * Config().fusion.rate_hz, abs=2)
    assert blocking["task"]["mode"] == "blocking" and blocking["task"]["cycles"] >= 2
    # The paper's move-and-wait loop trails a target moving at 10 cm/s by far more.
    assert summary["rms_error_mm_blocking"] > 2.0 * summary["rms_error_mm_servo"]
    assert result["calibration"]["translation_mm"] == pytest.approx(2.0)
    with pytest.raises(ConfigError, match="settle_s"):
        evaluate_follow(Config(), duration_s=1.0, settle_s=2.0)


def test_follows_a_bottle_track() -> None:
    """A bottle standing on the table, seen by the object stage only (10 Hz renders)."""
    from armvision.sim.scene import ObjectSpec, generate_scene

    config = _config()
    config = dataclasses.replace(
        config,
        runtime=dataclasses.replace(config.runtime, object_detection=True, tag_detection=False),
    )
    bottle = ObjectSpec("bottle0", "bottle", 0.03, 0.2, 0.5, "water", x=0.42, y=-0.06)
    scene = dataclasses.replace(generate_scene(config, 5), objects=(bottle,))
    system = sim_system(config, seed=5, scene=scene)
    world = system.world
    with system:
        system.pump(world.time + 1.0)  # the track is confirmed
        status = system.run_task("follow", follow, target="bottle", duration_s=3.0)
        T_ee = world.T_base_ee()
        T_obj = world.T_base_object("bottle0")
    assert status.phase == "succeeded", status.error
    assert status.result["target"].startswith("bottle track")
    centre = T_obj[:3, 3] + T_obj[:3, 2] * bottle.height / 2.0
    p_des = desired_ee_pose(centre, config.follow.standoff, config.follow.height_offset)[:3, 3]
    assert np.linalg.norm(T_ee[:3, 3] - p_des) < 0.015


def test_follow_refuses_the_gripper_tag() -> None:
    config = _config()
    system = sim_system(config, seed=3)
    with system:
        status = system.run_task("follow", follow, target="tag", tag_id=config.tag.id)
    assert status.phase == "failed" and "gripper's own tag" in status.error
