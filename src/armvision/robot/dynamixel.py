"""The ViperX-300s driven directly over its Dynamixel bus (U2D2, Protocol 2.0), with no ROS.

This is the only module that imports ROBOTIS's ``dynamixel_sdk``, and it does so only when a
:class:`DynamixelBus` is opened (``robot.backend = "dynamixel"``). The bus is the one Interbotix
configures (:data:`armvision.robot.xseries.VX300S_BUS`): 1 Mbps, nine servos, two shadows.

What it gives that the Interbotix API does not:

- one group sync read of position, velocity and current of every servo, at ``state_rate_hz``
  (200 by default) in a thread: :meth:`DynamixelArm.joint_state` has velocities and efforts;
- the hardware-error status of every servo: the alert bit of each status packet is watched and a
  fault (overload, overheating, input voltage, encoder, lost contact) stops every command,
  holds the arm where it is and says which joint and what, with the reboot to clear it;
- the gripper in current-based position mode with its current limit from
  ``robot.gripper_pressure``, and a grasp confirmed by current and finger gap together;
- torque off / on (:meth:`DynamixelArm.relax`, to move the arm by hand);
- errors that say what to do for a missing port, no permission, silent servos, a wrong baud
  rate or a wrong servo model.

Moves are Interbotix's: the time-based profile (Drive_Mode bit 2) with Profile_Velocity =
moving time and Profile_Acceleration = accel time in ms, checked first by :class:`ArmBase`.
"""

from __future__ import annotations

import contextlib
import errno
import glob
import importlib
import importlib.util
import logging
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from armvision.errors import HardwareError
from armvision.robot import xseries as xs
from armvision.robot.base import (
    DEFAULT_ACCEL_TIME_S,
    DEFAULT_MOVING_TIME_S,
    ArmBase,
    Array,
    Gripper,
    GripperBase,
    TrapezoidalTrajectory,
)
from armvision.robot.kinematics import VX300S, ArmModel

log = logging.getLogger("armvision.robot")

DEFAULT_PORT = "/dev/ttyDXL"
#: Streamed targets use a short acceleration-free profile, as the Interbotix backend does.
STREAM_MOVING_TIME_S = 0.1
#: Consecutive failed state reads before contact with a servo counts as lost.
MAX_READ_FAILURES = 3
#: A grasp holds when the gripper draws this share of its Goal_Current ...
GRASP_CURRENT_SHARE = 0.5
#: ... and the fingers stopped at least this far (m) short of closed: something is between them.
GRASP_MIN_GAP_M = 0.003
BAUD_CANDIDATES = (57600, 1_000_000, 115200, 2_000_000, 3_000_000, 4_000_000, 9600)

UDEV_HINT = (
    "add yourself to the dialout group (`sudo usermod -aG dialout $USER`, then log in again) "
    "or install Interbotix's udev rule, /etc/udev/rules.d/99-interbotix-udev.rules: "
    'SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", ATTRS{idProduct}=="6014", '
    'ATTR{device/latency_timer}="1", MODE:="0666", SYMLINK+="ttyDXL" '
    "(then `sudo udevadm control --reload && sudo udevadm trigger`)"
)


def find_u2d2_ports() -> list[str]:
    """Serial ports that look like a U2D2 (FTDI FT232H): ttyDXL, by-id FTDI names, ttyUSB*."""
    found = [p for p in ("/dev/ttyDXL",) if os.path.exists(p)]
    found += sorted(glob.glob("/dev/serial/by-id/*FTDI*") + glob.glob("/dev/serial/by-id/*U2D2*"))
    found += sorted(glob.glob("/dev/ttyUSB*"))
    return list(dict.fromkeys(found))


def scan(
    ports: list[str] | None = None,
    baud_rate: int = xs.VX300S_BAUD_RATE,
    servos: tuple[xs.BusServo, ...] = xs.VX300S_BUS,
    latency_ms: float = 16.0,
) -> tuple[bool, str]:
    """``armvision info``: the U2D2 ports found and which of the arm's IDs answer on each
    (with their model numbers checked). (usable, detail)."""
    if importlib.util.find_spec("dynamixel_sdk") is None:
        return False, "dynamixel-sdk not installed: `pip install 'armvision[dynamixel]'`"
    ports = find_u2d2_ports() if ports is None else ports
    if not ports:
        return False, "no U2D2 found (/dev/ttyDXL, /dev/serial/by-id/*FTDI*, /dev/ttyUSB*)"
    found, ok = [], False
    for port in ports:
        bus = DynamixelBus(port, baud_rate, servos, latency_ms=latency_ms, retries=0)
        try:
            bus.open()
        except HardwareError as exc:
            found.append(f"{port}: {exc}")
            continue
        try:
            models = {s.id: bus.ping(s.id)[0] for s in servos}
        finally:
            bus.close()
        answer = [i for i, m in models.items() if m is not None]
        wrong = [bus.name(s.id) for s in servos if models[s.id] not in (None, s.model.number)]
        silent = [i for i, m in models.items() if m is None]
        text = f"{port} at {baud_rate} bps: IDs {answer or 'none'} answer"
        if silent:
            text += f", IDs {silent} do not"
        if wrong:
            text += f"; wrong model: {', '.join(wrong)}"
        ok = ok or (not silent and not wrong)
        found.append(text)
    return ok, "; ".join(found)


def _port_handler(sdk: Any, name: str, latency_ms: float) -> Any:
    """The SDK's PortHandler with its packet timeout computed from ``latency_ms`` instead of
    the SDK's fixed 16 ms (the U2D2's FTDI latency timer; an emulated bus on a loaded machine
    needs more)."""

    class Port(sdk.PortHandler):
        def setPacketTimeout(self, packet_length: int) -> None:
            self.packet_start_time = self.getCurrentTime()
            self.packet_timeout = self.tx_time_per_byte * packet_length + 2.0 * latency_ms + 2.0

    return Port(name)


def _sdk() -> Any:
    try:
        return importlib.import_module("dynamixel_sdk")
    except ImportError:
        raise HardwareError(
            "robot.backend = 'dynamixel' needs ROBOTIS's dynamixel-sdk: "
            "`pip install 'armvision[dynamixel]'` (or `pip install dynamixel-sdk`)"
        ) from None


@dataclass(frozen=True)
class JointState:
    """One sync read of the arm: joint order is ``model.joint_names``; ``t`` is monotonic s."""

    t: float
    positions: Array  # rad
    velocities: Array  # rad/s
    efforts: Array  # N·m, master + shadow
    currents: Array  # A, master + shadow
    finger_position: float  # m, one finger's travel
    gripper_current: float  # A


@dataclass(frozen=True)
class DynamixelFault:
    """A servo that stopped the arm: which, and why."""

    servo: str
    id: int
    joint: str
    what: str

    def message(self) -> str:
        return (
            f"{self.joint} servo {self.servo} (ID {self.id}): {self.what}. The arm has stopped "
            f"and holds where it can; fix the cause, then `arm.reboot_servo('{self.servo}')` "
            "(or power-cycle the arm) and move it home"
        )


def _to_bytes(value: int, size: int) -> list[int]:
    return list(int(value).to_bytes(size, "little", signed=value < 0))


class DynamixelBus:
    """The servos on one port: ping, read, write, sync read/write, with errors that say why.

    Every transaction holds ``lock`` (the SDK is not thread-safe).
    """

    def __init__(
        self,
        port: str = DEFAULT_PORT,
        baud_rate: int = xs.VX300S_BAUD_RATE,
        servos: tuple[xs.BusServo, ...] = xs.VX300S_BUS,
        latency_ms: float = 16.0,
        retries: int = 2,
    ) -> None:
        self.port_name = port
        self.latency_ms = float(latency_ms)
        self.retries = int(retries)
        self.baud_rate = int(baud_rate)
        self.servos = servos
        self.by_id = {s.id: s for s in servos}
        self.lock = threading.RLock()
        self.sdk = _sdk()
        self.port: Any = None
        self.ph: Any = self.sdk.PacketHandler(2.0)

    # ---------------------------------------------------------------- port

    def open(self) -> None:
        if not os.path.exists(self.port_name) and self.port_name == DEFAULT_PORT:
            found = find_u2d2_ports()
            if found:  # no Interbotix udev rule: the first U2D2 there is
                log.warning("no %s; using %s (set robot.port to choose)", DEFAULT_PORT, found[0])
                self.port_name = found[0]
        if not os.path.exists(self.port_name):
            found = [p for p in find_u2d2_ports() if p != self.port_name]
            hint = f"found {', '.join(found)}: set robot.port" if found else "no U2D2 port found"
            raise HardwareError(
                f"no serial port {self.port_name}: is the U2D2 plugged in over USB? ({hint}; "
                f"/dev/ttyDXL is the name Interbotix's udev rule gives it)"
            )
        if not os.access(self.port_name, os.R_OK | os.W_OK):
            raise HardwareError(f"no permission to open {self.port_name}: {UDEV_HINT}")
        self.port = _port_handler(self.sdk, self.port_name, self.latency_ms)
        try:
            ok = self.port.setBaudRate(self.baud_rate)
        except Exception as exc:  # pyserial's SerialException wraps the OSError
            if getattr(exc, "errno", None) == errno.EACCES or "ermission" in str(exc):
                raise HardwareError(
                    f"no permission to open {self.port_name}: {UDEV_HINT}"
                ) from None
            raise HardwareError(f"cannot open {self.port_name}: {exc}") from None
        if not ok:
            raise HardwareError(
                f"{self.baud_rate} bps is not a baud rate the U2D2 driver supports: use "
                f"{xs.VX300S_BAUD_RATE} (the vx300s's Baud_Rate 3)"
            )

    def close(self) -> None:
        if self.port is not None and self.port.is_open:
            self.port.closePort()

    def set_baud_rate(self, baud_rate: int) -> None:
        with self.lock:
            self.port.setBaudRate(baud_rate)
            self.baud_rate = baud_rate

    # ---------------------------------------------------------------- transactions

    def name(self, dxl_id: int) -> str:
        servo = self.by_id.get(dxl_id)
        return f"{servo.name} (ID {dxl_id})" if servo else f"ID {dxl_id}"

    def _check(self, dxl_id: int, what: str, result: int, error: int) -> None:
        if result != self.sdk.COMM_SUCCESS:
            raise HardwareError(f"{self.name(dxl_id)} {what}: {self._comm_text(result)}")
        number = error & 0x7F
        if number:
            raise HardwareError(
                f"{self.name(dxl_id)} refused {what}: {xs.STATUS_ERRORS.get(number, number)}"
            )

    def _comm_text(self, result: int) -> str:
        if result == self.sdk.COMM_RX_TIMEOUT:
            return "no answer (timeout): is it powered and its cable plugged in?"
        if result == self.sdk.COMM_RX_CORRUPT:
            return "corrupt status packet (CRC error): noise on the bus? check the cables"
        return str(self.ph.getTxRxResult(result))

    def _retry(self, fn: Any, *args: Any, retries: int | None = None) -> Any:
        """``fn(port, *args)`` again (up to ``retries`` times) while the line fails: a lost
        packet is retried, a servo's refusal (status error) is not."""
        for _ in range((self.retries if retries is None else retries) + 1):
            with self.lock:
                out = fn(self.port, *args)
            result = out[1] if len(out) == 3 else out[0]
            if result == self.sdk.COMM_SUCCESS:
                break
        return out

    def ping(self, dxl_id: int, retries: int | None = None) -> tuple[int | None, int]:
        """(model number or None if it did not answer, SDK result)."""
        model, result, _ = self._retry(self.ph.ping, dxl_id, retries=retries)
        return (int(model) if result == self.sdk.COMM_SUCCESS else None), result

    def silent_ids(self, ids: list[int]) -> list[int]:
        """Which of ``ids`` do not answer a ping on time with their own model number, asked
        once the line has gone quiet (a late answer to an earlier request, matched by ID only,
        would parse as a wrong model number)."""
        with self.lock:
            time.sleep(2.0 * self.latency_ms / 1000.0)
            self.port.clearPort()
            pings = {i: self.ping(i, retries=0)[0] for i in ids}
        return [
            i
            for i, model in pings.items()
            if i in self.by_id and model != self.by_id[i].model.number
        ]

    def read(self, dxl_id: int, reg: tuple[int, int]) -> int:
        addr, size = reg
        data, result, error = self._retry(self.ph.readTxRx, dxl_id, addr, size)
        self._check(dxl_id, f"read of address {addr}", result, error)
        return int.from_bytes(bytes(data), "little", signed=addr in xs.SIGNED)

    def write(self, dxl_id: int, reg: tuple[int, int], value: int) -> None:
        addr, size = reg
        result, error = self._retry(self.ph.writeTxRx, dxl_id, addr, size, _to_bytes(value, size))
        self._check(dxl_id, f"write of {value} at address {addr}", result, error)

    def sync_write(self, addr: int, size: int, rows: dict[int, list[int]]) -> None:
        """One sync write of ``size`` bytes at ``addr`` to each ID (values as little-endian)."""
        with self.lock:
            group = self.sdk.GroupSyncWrite(self.port, self.ph, addr, size)
            for dxl_id, data in rows.items():
                group.addParam(dxl_id, data)
            result = group.txPacket()
        if result != self.sdk.COMM_SUCCESS:
            raise HardwareError(f"sync write at address {addr} failed: {self._comm_text(result)}")

    def sync_read(
        self, ids: list[int], addr: int, size: int
    ) -> tuple[dict[int, bytes], dict[int, int], dict[int, int]]:
        """One sync read: (data by ID, error byte by ID, failed SDK result by ID).

        The SDK's GroupSyncRead drops each status packet's error byte; its alert bit is how a
        servo says it has a hardware error, so the answers are read here one by one instead.
        """
        data: dict[int, bytes] = {}
        errors: dict[int, int] = {}
        failed: dict[int, int] = {}
        with self.lock:
            result = self.ph.syncReadTx(self.port, addr, size, ids, len(ids), False)
            if result != self.sdk.COMM_SUCCESS:
                return data, errors, {i: result for i in ids}
            for dxl_id in ids:
                raw, result, error = self.ph.readRx(self.port, dxl_id, size)
                if result == self.sdk.COMM_SUCCESS:
                    data[dxl_id], errors[dxl_id] = bytes(raw), int(error)
                else:
                    failed[dxl_id] = result
        return data, errors, failed

    def reboot(self, dxl_id: int) -> None:
        with self.lock:
            result, error = self.ph.reboot(self.port, dxl_id)
        self._check(dxl_id, "reboot", result, error & 0x7F)

    # ---------------------------------------------------------------- bring-up checks

    def check_servos(self) -> None:
        """Every servo answers with the right model number, or HardwareError saying which."""
        answered = {s.id: self.ping(s.id, retries=0)[0] for s in self.servos}
        if all(m is None for m in answered.values()):
            self._diagnose_silence()
        for i, m in answered.items():
            if m is None:  # one lost packet is not a missing servo
                answered[i] = self.ping(i)[0]
        missing = [i for i, m in answered.items() if m is None]
        if missing:
            names = ", ".join(self.name(i) for i in missing)
            raise HardwareError(
                f"servos not answering on {self.port_name}: {names}. The others answer, so "
                "check the cable into each of these (the bus is a daisy chain) and that no two "
                "servos share an ID"
            )
        for s in self.servos:
            model = answered[s.id]
            if model != s.model.number:
                raise HardwareError(
                    f"{self.name(s.id)} is model number {model}, expected {s.model.name} "
                    f"({s.model.number}) on a vx300s: is this the right arm, or a servo replaced "
                    "with another model?"
                )

    def _diagnose_silence(self) -> None:
        ids = [s.id for s in self.servos]
        configured = self.baud_rate
        for baud in BAUD_CANDIDATES:
            if baud == configured:
                continue
            self.set_baud_rate(baud)
            heard = [i for i in ids[:3] if self.ping(i, retries=0)[0] is not None]
            if heard:
                self.set_baud_rate(configured)
                raise HardwareError(
                    f"no servo answers at robot.baud_rate = {configured} bps but IDs {heard} "
                    f"answer at {baud} bps: set robot.baud_rate = {baud}, or set the servos' "
                    "Baud_Rate to 3 (1 Mbps, as Interbotix does) with Dynamixel Wizard"
                )
        self.set_baud_rate(configured)
        raise HardwareError(
            f"no servo answers on {self.port_name} at any baud rate: is the arm's 12 V supply "
            "on and the U2D2's 3-pin cable plugged into the arm?"
        )


class DynamixelGripper(GripperBase):
    """The gripper servo (ID 9) in current-based position mode.

    ``Goal_Current`` = ``pressure`` x Current_Limit bounds the squeeze; ``open``/``close`` set
    the goal and wait ``delay`` seconds (Interbotix's gripper delay, 1 s).
    """

    def __init__(self, arm: DynamixelArm, pressure: float, delay_s: float = 1.0) -> None:
        self._arm = arm
        self.servo = next(s for s in arm.bus.servos if s.joint == "gripper")
        self.pressure = float(pressure)
        self.delay_s = float(delay_s)
        self.goal_current = 0  # register units, set by configure()

    def configure(self) -> None:
        bus, i = self._arm.bus, self.servo.id
        limit = bus.read(i, xs.CURRENT_LIMIT)
        self.goal_current = max(round(self.pressure * limit), 1)
        bus.write(i, xs.GOAL_CURRENT, self.goal_current)

    def _goal(self, finger: float, delay: float | None) -> None:
        if self._arm.fault is not None:
            self._arm.last_error = self._arm.fault.message()
            log.warning("gripper: not moving. %s", self._arm.last_error)
            return
        tick = xs.rad_to_tick(xs.motor_angle_from_finger(finger))
        self._arm.bus.write(self.servo.id, xs.GOAL_POSITION, tick)
        wait = self.delay_s if delay is None else float(delay)
        if wait > 0.0:
            self._arm._wait(wait)

    def open(self, delay: float | None = None) -> None:
        """Fingers fully apart (0.057 m each)."""
        self._goal(VX300S.finger_limits[1], delay)

    def close(self, delay: float | None = None) -> None:
        """Fingers together, stopping on whatever is between them at the current limit."""
        self._goal(VX300S.finger_limits[0], delay)

    def get_finger_position(self) -> float:
        """One finger's travel, metres, from the motor angle through the horn linkage."""
        return self._arm.joint_state().finger_position

    def grasp_confirmed(self) -> bool:
        """An object is held: the motor pushes at (half) its current goal and the fingers
        stopped short of closed. Neither alone is enough (a stall with nothing in between,
        fingers apart while still closing)."""
        state = self._arm.joint_state()
        pushing = abs(state.gripper_current) >= (
            GRASP_CURRENT_SHARE * self.goal_current * xs.CURRENT_A_PER_LSB
        )
        gap = state.finger_position - VX300S.finger_limits[0] >= GRASP_MIN_GAP_M
        return bool(pushing and gap)


class DynamixelArm(ArmBase):
    """armvision's :class:`Arm` on the ViperX-300s's own bus (see the module docstring).

    Connecting checks the port, that every servo answers with its model number, and sets each
    servo's Drive_Mode (reverse where vx300s.yaml says, time-based profile) and Operating_Mode
    (position; current-based position for the gripper), touching EEPROM only where it differs.
    Then a thread reads the joint state at ``state_rate_hz``.
    """

    def __init__(
        self,
        port: str = DEFAULT_PORT,
        baud_rate: int = xs.VX300S_BAUD_RATE,
        model: ArmModel = VX300S,
        moving_time: float = DEFAULT_MOVING_TIME_S,
        accel_time: float = DEFAULT_ACCEL_TIME_S,
        gripper_pressure: float = 0.5,
        state_rate_hz: float = 200.0,
        latency_ms: float = 16.0,
        clock: Callable[[], float] | None = None,
        sleep: Callable[[float], None] | None = None,
    ) -> None:
        super().__init__(model, moving_time, accel_time)
        # The clock moves and waits are timed on, and how to wait: the wall clock by default; a
        # lockstep simulation behind an emulated bus passes its own (its time moves only when
        # someone waits).
        self._clock = clock or time.monotonic
        self._sleep = sleep or time.sleep
        self.bus = DynamixelBus(port, baud_rate, latency_ms=latency_ms)
        self.fault: DynamixelFault | None = None
        self.state_rate_hz = float(state_rate_hz)
        self.reads = 0  # successful state reads, for the benchmark
        self._state: JointState | None = None
        self._last_read: JointState | None = None  # what get_joint_positions last returned
        self._bad_reads = 0  # state reads in a row that failed
        self._ticks: dict[int, int] = {}  # latest Present_Position each servo answered
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._joint_servos = [
            [s for s in self.bus.servos if s.joint == name] for name in model.joint_names
        ]
        self._masters = [group[0] for group in self._joint_servos]
        self._ids = [s.id for s in self.bus.servos]
        self.dxl_gripper = DynamixelGripper(self, gripper_pressure)
        self.gripper: Gripper = self.dxl_gripper
        self.bus.open()
        try:
            self.bus.check_servos()
            self._configure()
            self._state = self._first_state()
            self.torque_on()
        except BaseException:
            self.bus.close()
            raise
        if self.state_rate_hz > 0.0:
            self._thread = threading.Thread(target=self._state_loop, name="dynamixel", daemon=True)
            self._thread.start()

    @classmethod
    def from_config(cls, robot: Any) -> DynamixelArm:
        """The arm ``config.robot`` describes (port, baud rate, timing, gripper pressure)."""
        return cls(
            port=robot.port,
            baud_rate=robot.baud_rate,
            moving_time=robot.moving_time,
            accel_time=robot.accel_time,
            gripper_pressure=robot.gripper_pressure,
        )

    # ---------------------------------------------------------------- bring-up

    def _configure(self) -> None:
        bus = self.bus
        for s in bus.servos:
            if s.is_shadow and bus.read(s.id, xs.SECONDARY_ID) != s.secondary_id:
                raise HardwareError(
                    f"{bus.name(s.id)} has Secondary_ID {bus.read(s.id, xs.SECONDARY_ID)}, "
                    f"expected {s.secondary_id}: it would not follow its master. Set it with "
                    "Dynamixel Wizard (or start Interbotix's xsarm_control once)"
                )
            drive = (xs.DRIVE_MODE_REVERSE if s.reverse else 0) | xs.DRIVE_MODE_TIME_BASED
            mode = (
                xs.OPERATING_MODE_CURRENT_BASED_POSITION
                if s.joint == "gripper"
                else xs.OPERATING_MODE_POSITION
            )
            have = (bus.read(s.id, xs.DRIVE_MODE), bus.read(s.id, xs.OPERATING_MODE))
            if have != (drive, mode):
                log.info("%s: Drive_Mode %s -> %s, Operating_Mode %s -> %s", bus.name(s.id),
                         have[0], drive, have[1], mode)  # fmt: skip
                bus.write(s.id, xs.TORQUE_ENABLE, 0)  # EEPROM is locked while torque is on
                bus.write(s.id, xs.DRIVE_MODE, drive)
                bus.write(s.id, xs.OPERATING_MODE, mode)
        self.dxl_gripper.configure()

    def torque_on(self) -> None:
        """Hold every servo where it is now (the goal is set to the present position first)."""
        with self.bus.lock:
            present = {i: self.bus.read(i, xs.PRESENT_POSITION) for i in self._ids}
            for i in self._ids:
                if not self.bus.by_id[i].is_shadow:
                    self.bus.write(i, xs.PROFILE_VELOCITY, 0)  # hold: no profile to play
                    self.bus.write(i, xs.GOAL_POSITION, present[i])
            for i in self._ids:
                self.bus.write(i, xs.TORQUE_ENABLE, 1)

    def relax(self) -> None:
        """Torque off on every arm servo, so the arm can be moved by hand. It falls under its
        own weight: support it first. :meth:`torque_on` holds it again."""
        self.halt()
        for s in self.bus.servos:
            if s.joint != "gripper":
                self.bus.write(s.id, xs.TORQUE_ENABLE, 0)

    # ---------------------------------------------------------------- state

    def _read_state(self) -> JointState:
        addr, size = xs.STATE_BLOCK
        data, errors, failed = self.bus.sync_read(self._ids, addr, size)
        for i, d in data.items():  # what Stop holds: each servo's latest answer
            self._ticks[i] = int.from_bytes(d[6:10], "little", signed=True)
        if failed:
            raise _ReadFailedError(failed)
        for dxl_id, error in errors.items():
            if error & xs.ERROR_ALERT:
                raise _AlertError(dxl_id)
        raw = {
            i: (
                int.from_bytes(d[0:2], "little", signed=True),
                int.from_bytes(d[2:6], "little", signed=True),
                int.from_bytes(d[6:10], "little", signed=True),
            )
            for i, d in data.items()
        }
        n = self.model.dof
        q, qd, amps, tau = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
        for j, group in enumerate(self._joint_servos):
            _current, velocity, position = raw[group[0].id]
            q[j] = xs.tick_to_rad(position)
            qd[j] = velocity * xs.RAD_S_PER_VELOCITY_LSB
            for s in group:
                a = raw[s.id][0] * xs.CURRENT_A_PER_LSB
                amps[j] += a
                tau[j] += a * s.model.torque_per_amp
        g = self.dxl_gripper.servo.id
        finger = xs.finger_from_motor_angle(xs.tick_to_rad(raw[g][2]))
        return JointState(
            time.monotonic(), q, qd, tau, amps, finger, raw[g][0] * xs.CURRENT_A_PER_LSB
        )

    def _first_state(self) -> JointState:
        """The state read at connection, a servo already in a hardware error as HardwareError."""
        try:
            return self._read_state()
        except _AlertError as alert:
            bits = self.bus.read(alert.id, xs.HARDWARE_ERROR_STATUS)
            raise HardwareError(
                f"{self.bus.name(alert.id)} reports hardware error status 0x{bits:02x}, "
                f"{xs.describe_hardware_error(bits)}: fix the cause and reboot it (power-cycle "
                "the arm, or DynamixelBus.reboot) before connecting"
            ) from None
        except _ReadFailedError as failure:
            names = ", ".join(self.bus.name(i) for i in failure.failed)
            raise HardwareError(f"the first state read failed for {names}") from None

    def _state_loop(self) -> None:
        period = 1.0 / self.state_rate_hz
        next_t = time.monotonic()
        while not self._stop.is_set():
            if self.fault is None:
                self.poll()
            next_t = max(next_t + period, time.monotonic())
            self._stop.wait(max(next_t - time.monotonic(), 0.0))

    def poll(self) -> JointState | None:
        """One state read; a fault it reveals is raised on the arm (see :meth:`_on_fault`)."""
        try:
            state = self._read_state()
        except _ReadFailedError as failure:
            self._bad_reads += 1
            if self._bad_reads >= MAX_READ_FAILURES:
                self._lost_contact(failure.failed)
            return None
        except _AlertError as alert:
            self._hardware_fault(alert.id)
            return None
        except HardwareError as exc:
            log.warning("dynamixel state read failed: %s", exc)
            return None
        self._bad_reads = 0
        self._state = state
        self.reads += 1
        return state

    def _lost_contact(self, failed: dict[int, int]) -> None:
        """Name the servos that stopped answering. The SDK reads a sync read's answers in
        order and drops what it skips, so one silent, late or garbled servo spoils the answers
        after it: the culprits are the servos that fail a ping of their own."""
        culprits = self.bus.silent_ids(self._ids)
        named = culprits or list(failed)
        i = named[0]
        result = failed.get(i, self.sdk_timeout)
        also = f"; also {', '.join(self.bus.name(j) for j in named[1:])}" if named[1:] else ""
        self._on_fault(
            i,
            f"lost contact: {self.bus._comm_text(result)} ({MAX_READ_FAILURES} state reads in "
            f"a row failed{also})",
            stale=set(culprits),
        )

    @property
    def sdk_timeout(self) -> int:
        return int(self.bus.sdk.COMM_RX_TIMEOUT)

    def _hardware_fault(self, dxl_id: int) -> None:
        bits = self.bus.read(dxl_id, xs.HARDWARE_ERROR_STATUS)
        what = xs.describe_hardware_error(bits)
        if bits & 0x01:
            volts = self.bus.read(dxl_id, xs.PRESENT_INPUT_VOLTAGE) * xs.VOLT_PER_LSB
            lo = self.bus.read(dxl_id, xs.MIN_VOLTAGE_LIMIT) * xs.VOLT_PER_LSB
            what += f" at {volts:.1f} V (limit {lo:.1f} V): check the 12 V supply"
        if bits & 0x20:
            what += ": it shut its torque off; reduce the load (a heavy object, a collision)"
        self._on_fault(dxl_id, f"hardware error status 0x{bits:02x}, {what}")

    def _on_fault(self, dxl_id: int, what: str, stale: set[int] | None = None) -> None:
        """Stop: refuse every later command, hold every servo that answers where it is
        (``stale``: servos not to ask, they hold their last known position)."""
        servo = self.bus.by_id[dxl_id]
        self.fault = DynamixelFault(servo.name, dxl_id, servo.joint, what)
        self.last_error = self.fault.message()
        log.error("%s", self.last_error)
        self._motion_end = -math.inf
        self._last_stream = None
        self._hold_present(stale or set())

    def _hold_present(self, stale: set[int]) -> None:
        """Goal = the present position of every arm master (the gripper is left as it is, so a
        held object stays held). Each is read afresh except the ``stale`` ones, which hold
        their last state read's position: a late answer from one of them could pass for the
        reply to a new read (the SDK matches answers by ID only)."""
        for s in self._masters:
            if s.id not in stale:
                with contextlib.suppress(HardwareError):
                    self._ticks[s.id] = self.bus.read(s.id, xs.PRESENT_POSITION)
        rows = {
            s.id: _to_bytes(0, 4) + _to_bytes(STREAM_MS, 4) + _to_bytes(self._ticks[s.id], 4)
            for s in self._masters
            if s.id in self._ticks
        }
        if rows:
            self.bus.sync_write(xs.PROFILE_ACCELERATION[0], 12, rows)

    def joint_state(self) -> JointState:
        """The latest sync read (at most 1 / ``state_rate_hz`` old; with ``state_rate_hz`` 0
        there is no reading thread and this reads now)."""
        if self._thread is None and self.fault is None:
            self.poll()
        state = self._state
        if state is None:  # pragma: no cover - set before the thread starts
            raise HardwareError("no joint state read yet")
        return state

    def reboot_servo(self, name: str) -> None:
        """Reboot one servo (clears its hardware error if the cause is gone), torque it on
        holding where it is, and clear the fault if none is left."""
        servo = next((s for s in self.bus.servos if s.name == name), None)
        if servo is None:
            raise ValueError(f"no servo {name!r}; servos: {[s.name for s in self.bus.servos]}")
        self.bus.reboot(servo.id)
        time.sleep(0.3)  # the firmware restarts
        self._bad_reads = 0
        self.fault = None
        self.last_error = None
        if servo.joint == "gripper":
            self._configure()
        self.torque_on()

    # ---------------------------------------------------------------- ArmBase hooks

    def _read_joint_positions(self) -> Array:
        state = self.joint_state()
        self._last_read = state
        return state.positions.copy()

    def get_joint_velocities(self) -> Array:
        """Present_Velocity of the reading the last :meth:`get_joint_positions` returned
        (the latest one if there was none), rad/s."""
        state = self._last_read if self._last_read is not None else self.joint_state()
        return state.velocities.copy()

    def _profile_rows(self, q: Array, moving_ms: int, accel_ms: int) -> dict[int, list[int]]:
        """Profile_Acceleration, Profile_Velocity, Goal_Position (addresses 108-119) per master;
        the shadows take their master's through Secondary_ID."""
        return {
            s.id: _to_bytes(accel_ms, 4)
            + _to_bytes(moving_ms, 4)
            + _to_bytes(xs.rad_to_tick(qj), 4)
            for s, qj in zip(self._masters, q)
        }

    def _execute(self, trajectory: TrapezoidalTrajectory, blocking: bool) -> None:
        moving_ms = round(trajectory.moving_time * 1000.0)
        accel_ms = round(trajectory.accel_time * 1000.0)
        rows = self._profile_rows(trajectory.q_goal, moving_ms, accel_ms)
        self.bus.sync_write(xs.PROFILE_ACCELERATION[0], 12, rows)
        if blocking:
            self._wait(trajectory.moving_time + self.settle_time)

    def _stream(self, q: Array) -> None:
        self.bus.sync_write(xs.PROFILE_ACCELERATION[0], 12, self._profile_rows(q, STREAM_MS, 0))

    def _halt(self) -> None:
        self._hold_present(set())

    def _now(self) -> float:
        return self._clock()

    def _wait(self, seconds: float) -> None:
        """Wait ``seconds`` on the arm's clock, ending early on a fault (found by the reading
        thread, or by a read every 20 ms without one)."""
        end = self._clock() + seconds
        while self.fault is None and (left := end - self._clock()) > 0.0:
            self._sleep(min(left, 0.01 if self._thread is not None else 0.02))
            if self._thread is None:
                self.poll()

    # ---------------------------------------------------------------- commands refuse on a fault

    def set_joint_positions(
        self,
        joint_positions: Any,
        moving_time: float | None = None,
        accel_time: float | None = None,
        blocking: bool = True,
    ) -> bool:
        if self.fault is not None:
            return self._fail(self.fault.message())
        ok = super().set_joint_positions(joint_positions, moving_time, accel_time, blocking)
        if self.fault is not None:  # during the move
            return self._fail(self.fault.message())
        return ok

    def stream_joint_targets(self, joint_positions: Any) -> bool:
        if self.fault is not None:
            return self._fail(self.fault.message())
        return super().stream_joint_targets(joint_positions)

    def close(self) -> None:
        """Stop the state thread and close the port; the servos keep holding (torque on)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self.bus.close()


STREAM_MS = round(STREAM_MOVING_TIME_S * 1000)


class _ReadFailedError(Exception):
    def __init__(self, failed: dict[int, int]) -> None:
        super().__init__(failed)
        self.failed = failed


class _AlertError(Exception):
    def __init__(self, dxl_id: int) -> None:
        super().__init__(dxl_id)
        self.id = dxl_id
