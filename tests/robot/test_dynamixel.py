"""The Dynamixel driver through ROBOTIS's real dynamixel-sdk, against the servo-bus emulator on a
pseudo-terminal, backed by the simulation: the simulator is the truth every reading and every
move is checked against. Everything runs on the wall clock (SimWorld realtime mode)."""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Iterator

import numpy as np
import pytest

from armvision.config import Config
from armvision.errors import HardwareError
from armvision.geometry import make_T, rpy_to_R
from armvision.robot import xseries as xs
from armvision.robot.base import TrapezoidalTrajectory
from armvision.robot.kinematics import VX300S
from armvision.sim.scene import ObjectSpec, SceneSpec, random_camera_pose
from armvision.sim.servo_bus import ServoBusEmulator
from armvision.sim.world import SimWorld

sdk = pytest.importorskip("dynamixel_sdk")
from armvision.robot.dynamixel import DynamixelArm, scan  # noqa: E402 - after the importorskip

#: The bus's packet latency: the emulator shares two loaded cores with the simulation and the
#: tests, so it may answer later than a U2D2's 16 ms.
LATENCY_MS = 100.0
#: A reached target: under 3 ticks (0.0015 rad each), the servos still settling 0.1 s after.
REACH_RAD = 0.004


def _empty() -> Config:
    c = Config()
    return dataclasses.replace(
        c, sim=dataclasses.replace(c.sim, min_objects=0, max_objects=0, loose_tags=0)
    )


class Bench:
    def __init__(self, scene: SceneSpec | None = None, **arm_kwargs) -> None:
        self.world = SimWorld(_empty(), 0, mode="realtime", scene=scene)
        self.bus = ServoBusEmulator(self.world).start()
        self.arm: DynamixelArm | None = None
        self.arm_kwargs = arm_kwargs

    def connect(self, **kwargs) -> DynamixelArm:
        kwargs = {"latency_ms": LATENCY_MS, **self.arm_kwargs, **kwargs}
        self.arm = DynamixelArm(self.bus.port, **kwargs)
        return self.arm

    def close(self) -> None:
        if self.arm is not None:
            self.arm.close()
        self.bus.close()
        self.world.close()


@pytest.fixture
def bench() -> Iterator[Bench]:
    b = Bench()
    yield b
    b.close()


@pytest.fixture(scope="module")
def shared() -> Iterator[Bench]:
    """One emulated arm for the tests that leave it healthy."""
    b = Bench()
    b.connect()
    yield b
    b.close()


def _raw(port: str, monkeypatch: pytest.MonkeyPatch):
    """The SDK's own port and packet handler, with the loaded machine's latency."""
    monkeypatch.setattr(sdk.port_handler, "LATENCY_TIMER", LATENCY_MS)
    ph = sdk.PacketHandler(2.0)
    p = sdk.PortHandler(port)
    assert p.openPort()
    return p, ph


def _arrive(world: SimWorld, q: np.ndarray, timeout: float = 1.5) -> float:
    """Largest joint error (rad) once the simulated arm is within REACH_RAD of ``q``, or at
    ``timeout``: on a loaded machine the realtime physics may run behind the wall clock."""
    deadline = time.monotonic() + timeout
    while True:
        err = float(np.abs(world.joint_positions() - q).max())
        if err < REACH_RAD or time.monotonic() > deadline:
            return err
        time.sleep(0.02)


def _still(world: SimWorld, seconds: float = 0.4, within: float = 1.5) -> float:
    """How far (rad) any joint moved over ``seconds``, once it has come to rest (within
    ``within`` s: the hold's profile may run behind the wall clock on a loaded machine)."""
    deadline = time.monotonic() + within
    while True:
        q0 = world.joint_positions()
        time.sleep(seconds)
        moved = float(np.abs(world.joint_positions() - q0).max())
        if moved < 0.002 or time.monotonic() > deadline:
            return moved


# --------------------------------------------------------------------------- the emulator alone


def test_emulator_answers_the_sdk_as_the_servos_would(bench: Bench, monkeypatch) -> None:
    port, ph = _raw(bench.bus.port, monkeypatch)
    try:
        found, result = ph.broadcastPing(port)
        assert result == sdk.COMM_SUCCESS
        assert {i: m for i, (m, _) in found.items()} == {
            s.id: s.model.number for s in xs.VX300S_BUS
        }
        # Present_Position is the simulated joint in ticks, shadows equal to their masters.
        q = bench.world.joint_positions()
        pos = {i: ph.read4ByteTxRx(port, i, 132)[0] for i in range(1, 9)}
        assert pos[2] == pos[3] == xs.rad_to_tick(q[1])
        assert pos[4] == pos[5] == xs.rad_to_tick(q[2])
        # EEPROM with torque on: access error; a goal past Max_Position_Limit: data limit.
        _, error = ph.write1ByteTxRx(port, 1, 11, 3)
        assert error == 7
        _, error = ph.write4ByteTxRx(port, 2, 116, 2900)  # shoulder max is 2867
        assert error == 6
        # An instruction with a bad CRC gets a status with the CRC error number.
        bad = bytearray(bytes.fromhex("FF FF FD 00 01 03 00 01 19 4F"))
        port.clearPort()
        port.writePort(bad)
        time.sleep(0.05)
        reply = bytes(port.readPort(64))
        assert reply[7:9] == bytes([0x55, 3]) and bench.bus.crc_errors == 1
        # Reboot: RAM to defaults, so the torque is off after it.
        assert ph.reboot(port, 8)[0] == sdk.COMM_SUCCESS
        assert ph.read1ByteTxRx(port, 8, 64)[0] == 0
    finally:
        port.closePort()


# --------------------------------------------------------------------------- moves


def test_home_sleep_and_moves_reach_their_targets_in_the_simulation(shared: Bench) -> None:
    arm, world = shared.arm, shared.world
    assert arm is not None
    targets = [
        VX300S.home,
        np.array([0.5, -0.4, 0.6, 0.3, -0.7, 0.4]),
        np.array([-0.8, 0.3, -0.2, -0.5, 1.1, -1.2]),
        VX300S.sleep,
    ]
    for q in targets:
        t0 = time.monotonic()
        assert arm.set_joint_positions(q, moving_time=1.0, accel_time=0.2), arm.last_error
        assert 1.0 <= time.monotonic() - t0 < 1.5  # the profile's time (+ a loaded machine)
        assert _arrive(world, q) < REACH_RAD, q
        time.sleep(0.05)
        assert np.abs(arm.get_joint_positions() - q).max() < REACH_RAD
    assert arm.go_to_home_pose(moving_time=1.0)
    assert _arrive(world, VX300S.home) < REACH_RAD


def test_the_servos_play_the_time_based_profile(shared: Bench) -> None:
    """Through a 1.2 s move with 0.3 s ramps the joint is where Interbotix's trapezoid says,
    on the simulation's clock (the servos run their profile on it)."""
    arm, world = shared.arm, shared.world
    assert arm is not None and arm.go_to_home_pose(moving_time=1.0)
    assert _arrive(world, VX300S.home) < REACH_RAD
    target = np.array([0.9, 0.0, 0.0, 0.0, 0.0, 0.0])
    plan = TrapezoidalTrajectory.plan(np.zeros(6), target, 1.2, 0.3)
    t0 = world.time
    assert arm.set_joint_positions(target, moving_time=1.2, accel_time=0.3, blocking=False)
    seen, cruise = [], []
    while (t := world.time) - t0 < 1.1:
        with world.lock:
            t, q = world.time, world.joint_positions()[0]
        seen.append((t - t0, q, plan.sample(t - t0)[0][0]))
        if 0.45 < t - t0 < 0.75:  # cruising: the measured velocity is the simulated one
            cruise.append((arm.joint_state().velocities[0], world.joint_velocities()[0]))
        time.sleep(0.03)
    errors = [abs(q - expected) for _, q, expected in seen]
    assert max(errors) < 0.03, seen  # the command's bus latency is a few ms of the profile
    v_peak = 0.9 / (1.2 - 0.3)
    assert cruise and all(
        measured == pytest.approx(v_peak, rel=0.1) and true == pytest.approx(v_peak, rel=0.1)
        for measured, true in cruise
    ), cruise
    assert _arrive(world, target) < REACH_RAD


def test_reversed_joints_and_shadows_agree_with_the_simulation(shared: Bench) -> None:
    arm, world = shared.arm, shared.world
    assert arm is not None
    q = np.array([0.2, 0.5, -0.6, 0.0, 0.9, 0.0])  # shoulder, elbow, wrist_angle off centre
    assert arm.set_joint_positions(q, moving_time=1.0)
    assert _arrive(world, q) < REACH_RAD
    time.sleep(0.05)
    assert np.sign(world.joint_positions()[[1, 2, 4]]).tolist() == [1.0, -1.0, 1.0]
    for servo in xs.VX300S_BUS:
        emulated = shared.bus.servos[servo.id]
        assert emulated.get(xs.DRIVE_MODE) == (
            (xs.DRIVE_MODE_REVERSE if servo.reverse else 0) | xs.DRIVE_MODE_TIME_BASED
        )
    pos = {i: s.get(xs.PRESENT_POSITION) for i, s in shared.bus.servos.items()}
    assert pos[2] == pos[3] and pos[4] == pos[5]  # shadows read as their masters
    # Each shadow carries half its joint's load, in the same direction as its master.
    cur = {i: s.get(xs.PRESENT_CURRENT) for i, s in shared.bus.servos.items()}
    assert cur[2] == cur[3] and cur[4] == cur[5] and abs(cur[2]) > 10
    state = arm.joint_state()
    assert np.abs(state.positions - world.joint_positions()).max() < REACH_RAD
    # The effort is the simulated torque the motors give: the actuators plus the links' weight.
    with world.lock:
        d = world.data
        tau = d.actuator_force[world.arm_actuators] + d.qfrc_gravcomp[world._dofadr]
    assert state.efforts[1] == pytest.approx(tau[1], rel=0.05, abs=0.05)
    assert abs(state.efforts[1]) > 1.0  # the shoulder holds the arm up
    assert arm.go_to_home_pose(moving_time=1.0)


def test_a_wrongly_configured_reverse_bit_shows_as_a_mirrored_joint(
    bench: Bench, monkeypatch
) -> None:
    """The emulator's mirror-image mounts have teeth: without Drive_Mode's reverse bit the
    shoulder master reads the joint backwards, as the real one would."""
    port, ph = _raw(bench.bus.port, monkeypatch)
    try:
        q = bench.world.joint_positions()[1]
        assert ph.write1ByteTxRx(port, 2, 64, 0)[1] == 0
        assert ph.write1ByteTxRx(port, 2, 10, xs.DRIVE_MODE_TIME_BASED)[1] == 0
        tick = ph.read4ByteTxRx(port, 2, 132)[0]
        assert tick == xs.rad_to_tick(-q) != xs.rad_to_tick(q)
        assert ph.read4ByteTxRx(port, 3, 132)[0] == xs.rad_to_tick(q)
    finally:
        port.closePort()


def test_joint_state_reads_at_100_hz_or_more(shared: Bench) -> None:
    arm = shared.arm
    assert arm is not None
    n0, t0 = arm.reads, time.monotonic()
    time.sleep(1.0)
    rate = (arm.reads - n0) / (time.monotonic() - t0)
    print(f"\njoint-state sync reads through the emulator: {rate:.0f} Hz (target 200)")
    assert arm.reads > n0  # the rate itself is benchmarks/bench_dynamixel.py's


def test_stop_holds_the_position_mid_move(shared: Bench) -> None:
    arm, world = shared.arm, shared.world
    assert arm is not None and arm.go_to_home_pose(moving_time=1.0)
    assert arm.set_joint_positions([1.2, 0, 0, 0, 0, 0], moving_time=1.5, blocking=False)
    time.sleep(0.5)
    arm.halt()
    time.sleep(0.15)  # the hold's 100 ms profile
    q_stop = world.joint_positions()[0]
    assert 0.1 < q_stop < 1.0
    assert _still(world, 0.5) < 0.002
    assert not arm.moving
    assert arm.go_to_home_pose(moving_time=1.0)


def test_streamed_targets_are_followed(shared: Bench) -> None:
    arm, world = shared.arm, shared.world
    assert arm is not None and arm.go_to_home_pose(moving_time=1.0)
    for k in range(1, 21):
        q = np.array([0.02 * k, 0, 0, 0, 0, 0])
        assert arm.stream_joint_targets(q), arm.last_error
        time.sleep(0.05)
    assert _arrive(world, np.array([0.4, 0, 0, 0, 0, 0])) < REACH_RAD
    assert arm.go_to_home_pose(moving_time=1.0)


# --------------------------------------------------------------------------- gripper

BOTTLE = ObjectSpec(
    "bottle", "bottle", radius=0.032, height=0.2, fill=0.6, liquid="juice", x=0.42, y=0.05
)


def test_gripper_grasp_is_confirmed_by_current_and_gap_on_a_bottle() -> None:
    b = Bench(scene=SceneSpec(random_camera_pose(Config().sim, None), (BOTTLE,)))
    try:
        arm = b.connect(gripper_pressure=0.5)
        world = b.world
        arm.gripper.close(delay=0.8)  # nothing between the fingers: a stall is no grasp
        assert arm.gripper.get_finger_position() == pytest.approx(0.021, abs=1e-3)
        assert not arm.gripper.grasp_confirmed()
        p = world.T_base_object("bottle")[:3, 3]
        yaw = math.atan2(p[1], p[0])
        approach = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        up = np.array([0.0, 0.0, 0.45 * BOTTLE.body_height])

        def at(point: np.ndarray) -> np.ndarray:
            return make_T(rpy_to_R(0.0, 0.0, yaw), point)

        arm.gripper.open(delay=0.8)
        assert not arm.gripper.grasp_confirmed()
        assert arm.set_ee_pose_matrix(at(p - 0.12 * approach + up), moving_time=1.5)
        assert arm.set_ee_pose_matrix(at(p + up), moving_time=1.0)
        arm.gripper.close(delay=0.8)
        assert world.held_object() == "bottle"
        assert arm.gripper.grasp_confirmed()
        # The finger position from the motor angle is the simulated finger's.
        assert arm.gripper.get_finger_position() == pytest.approx(world.finger_position(), abs=1e-3)
        # The squeeze is the current goal: pressure 0.5 of Current_Limit.
        limit = b.bus.servos[9].get(xs.CURRENT_LIMIT)
        assert abs(arm.joint_state().gripper_current) == pytest.approx(
            0.5 * limit * xs.CURRENT_A_PER_LSB, rel=0.1
        )
    finally:
        b.close()


# --------------------------------------------------------------------------- relax


def test_relax_turns_the_torque_off_and_torque_on_holds_again(bench: Bench) -> None:
    arm = bench.connect()
    arm.relax()
    assert all(bench.bus.servos[i].get(xs.TORQUE_ENABLE) == 0 for i in range(1, 9))
    # Moved by hand: the waist turns freely (the simulation's links do not fall: gravcomp).
    with bench.world.lock:
        bench.world.data.qvel[bench.world._dofadr[0]] = 0.5
    time.sleep(0.3)
    turned = bench.world.joint_positions()[0]
    assert abs(turned) > 0.05
    arm.torque_on()
    time.sleep(0.1)
    q_held = bench.world.joint_positions()[0]
    assert _still(bench.world) < 0.002
    assert arm.get_joint_positions()[0] == pytest.approx(q_held, abs=REACH_RAD)


# --------------------------------------------------------------------------- faults


def _move_and_fault(bench: Bench, inject) -> tuple[DynamixelArm, str]:
    arm = bench.connect()
    assert arm.set_joint_positions([0.6, 0, 0, 0, 0, 0], moving_time=3.0, blocking=False)
    time.sleep(0.4)
    inject()
    deadline = time.monotonic() + 4.0
    while arm.fault is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert arm.fault is not None
    message = arm.fault.message()
    time.sleep(0.3)  # the hold's 100 ms profile, on a loaded machine
    assert _still(bench.world) < 0.002  # the arm holds still
    assert bench.world.joint_positions()[0] < 0.55  # the move was cut short
    assert not arm.set_joint_positions(VX300S.home, moving_time=1.0)  # refused
    assert arm.last_error == message
    return arm, message


def test_a_silent_servo_stops_the_arm_and_is_named(bench: Bench) -> None:
    _, message = _move_and_fault(bench, lambda: bench.bus.silence(3))
    assert "shoulder_shadow (ID 3)" in message and "lost contact" in message
    assert "no answer" in message


def test_crc_errors_stop_the_arm_and_are_named(bench: Bench) -> None:
    _, message = _move_and_fault(bench, lambda: bench.bus.corrupt_crc(6))
    assert "forearm_roll (ID 6)" in message and "CRC error" in message


def test_timeouts_stop_the_arm_and_are_named(bench: Bench) -> None:
    _, message = _move_and_fault(bench, lambda: bench.bus.delay(8, 3 * LATENCY_MS / 1000))
    assert "wrist_rotate (ID 8)" in message and "timeout" in message


def test_an_overload_stops_the_arm_names_the_joint_and_a_reboot_clears_it(bench: Bench) -> None:
    arm, message = _move_and_fault(bench, lambda: bench.bus.set_hardware_error(4, 0x20))
    assert message.startswith("elbow servo elbow (ID 4): hardware error status 0x20, overload")
    assert "reboot_servo('elbow')" in message
    assert bench.bus.servos[4].get(xs.TORQUE_ENABLE) == 0  # the firmware shut it down
    arm.reboot_servo("elbow")
    assert arm.fault is None and bench.bus.servos[4].get(xs.TORQUE_ENABLE) == 1
    assert arm.go_to_home_pose(moving_time=1.0), arm.last_error
    assert _arrive(bench.world, VX300S.home) < REACH_RAD


def test_a_voltage_drop_stops_the_arm_with_the_voltage(bench: Bench) -> None:
    _, message = _move_and_fault(bench, lambda: bench.bus.set_input_voltage(8.7))
    assert "input voltage error" in message and "at 8.7 V (limit 9.5 V)" in message
    assert "waist servo waist (ID 1)" in message  # the first servo that reports it


# --------------------------------------------------------------------------- bring-up errors


def test_a_missing_port_says_what_to_do(tmp_path) -> None:
    with pytest.raises(HardwareError, match=r"no serial port .*ttyDXL.* U2D2 plugged in"):
        DynamixelArm(str(tmp_path / "ttyDXL"))


def test_no_permission_gives_the_udev_and_dialout_fix(bench: Bench) -> None:
    os.chmod(bench.bus.port, 0o000)
    try:
        if os.access(bench.bus.port, os.R_OK):
            pytest.skip("running as root: permissions are not enforced")
        with pytest.raises(HardwareError, match=r"no permission .*dialout.*udev"):
            bench.connect()
    finally:
        os.chmod(bench.bus.port, 0o620)


def test_servos_that_do_not_answer_are_listed(bench: Bench) -> None:
    bench.bus.silence(5)
    bench.bus.silence(9)
    with pytest.raises(
        HardwareError, match=r"not answering .*elbow_shadow \(ID 5\), gripper \(ID 9\)"
    ):
        bench.connect()


def test_a_wrong_baud_rate_names_the_right_one(bench: Bench) -> None:
    with pytest.raises(
        HardwareError,
        match=r"no servo answers at robot.baud_rate = 57600 bps but IDs .* answer at 1000000",
    ):
        bench.connect(baud_rate=57600)


def test_a_wrong_model_number_is_named(bench: Bench) -> None:
    bench.bus.servos[8].put(xs.MODEL_NUMBER, xs.XM540_W270.number)
    with pytest.raises(
        HardwareError, match=r"wrist_rotate \(ID 8\) is model number 1120, expected XM430-W350"
    ):
        bench.connect()


def test_info_scan_pings_the_arm_s_ids_on_each_port(bench: Bench) -> None:
    ok, detail = scan([bench.bus.port], latency_ms=LATENCY_MS)
    assert (
        ok and f"{bench.bus.port} at 1000000 bps: IDs [1, 2, 3, 4, 5, 6, 7, 8, 9] answer" in detail
    )
    bench.bus.silence(7)
    ok, detail = scan([bench.bus.port], latency_ms=LATENCY_MS)
    assert not ok and "IDs [7] do not" in detail


def test_sim_arm_dynamixel_emulated_runs_lockstep_on_the_simulation_clock() -> None:
    """``sim.arm = "dynamixel-emulated"``: the system's arm is the driver over the emulator; in
    lockstep a blocking move advances the world by its moving time and reaches the target."""
    from armvision.bench.system import sim_system, sim_world

    config = _empty()
    config = dataclasses.replace(
        config, sim=dataclasses.replace(config.sim, arm="dynamixel-emulated")
    )
    with sim_system(config, 0) as system:
        arm, world = system.arm, sim_world(system)
        assert isinstance(arm, DynamixelArm) and system.lockstep
        t0 = world.time
        q = np.array([0.3, -0.2, 0.4, 0.0, 0.5, 0.2])
        assert arm.set_joint_positions(q, moving_time=1.0)
        assert world.time - t0 == pytest.approx(1.0, abs=0.03)
        assert np.abs(world.joint_positions() - q).max() < REACH_RAD
        assert np.abs(arm.get_joint_positions() - q).max() < REACH_RAD


def test_the_cli_arm_option_sets_sim_arm() -> None:
    from armvision.cli.main import build_parser, overrides

    args = build_parser().parse_args(["eval", "grab", "--arm", "dynamixel-emulated"])
    assert "sim.arm=dynamixel-emulated" in overrides(args)
    args = build_parser().parse_args(["grab", "--arm", "dynamixel-emulated"])
    assert "sim.arm=dynamixel-emulated" in overrides(args)
    args = build_parser().parse_args(["demo", "--arm", "dynamixel-emulated"])
    assert "sim.arm=dynamixel-emulated" in overrides(args)


def test_a_servo_already_in_a_hardware_error_is_named_at_connection(bench: Bench) -> None:
    bench.bus.set_hardware_error(7, 0x04)
    with pytest.raises(
        HardwareError, match=r"wrist_angle \(ID 7\) reports hardware error status 0x04, overheating"
    ):
        bench.connect()
