"""A Dynamixel Protocol 2.0 servo bus on a pseudo-terminal, backed by the simulated arm.

:class:`ServoBusEmulator` opens a pty pair (``os.openpty``) and answers on the master side, in a
thread, what nine X-series servos on a U2D2 would: ping, read, write, reg write / action, sync
read, sync write, bulk read, reboot, with the e-manual's packet format (CRC-16 polynomial 0x8005,
byte stuffing of FF FF FD) and status packets carrying the error field. Any Protocol 2.0 host
opens ``emulator.port`` (the slave's path) as it would ``/dev/ttyDXL``; ROBOTIS's
``dynamixel-sdk`` does, which is how the driver is tested.

Each servo holds its control table (:mod:`armvision.robot.xseries`), EEPROM as Interbotix's
vx300s.yaml leaves it. The joints are the SimWorld's: a Goal_Position write starts the servo's
own profile (time-based when Drive_Mode bit 2 is set, as Interbotix uses it), which a world
controller feeds to the MuJoCo position servos before every physics step; Present_Position and
Present_Velocity are the simulated joint's, Present_Current the simulated actuator torque plus
the gravity load (the model compensates gravity with ``gravcomp``, so the links' weight is added
back here) over the motor's torque constant, split between a master and its shadow. Because of
that compensation a joint whose torque is off does not fall in the simulation, as it would on
the real arm. Drive_Mode's reverse bit
is applied live: the masters of shoulder, elbow and wrist angle are mounted mirror-image, so a
host that does not set it reads the joint backwards, as on the real arm. A shadow (Secondary_ID
= its master's ID) takes every write addressed to its master and never answers it.

The gripper in current-based position mode (Operating_Mode 5) closes with a force of
``GRIPPER_MAX_FORCE_N`` x Goal_Current / Current_Limit, and reports the actuator force back as
current on the same scale: a squeezed bottle reads as the current limit.

Faults for tests: :meth:`silence` (an ID stops answering), :meth:`corrupt_crc` (its status
packets fail their CRC), :meth:`delay` (it answers after the host's timeout),
:meth:`set_hardware_error` (a Hardware_Error_Status bit: torque off when Shutdown says so,
alert bit in every status), :meth:`set_input_voltage` (below Min_Voltage_Limit sets the input
voltage error). The host's baud rate is read from the pty's termios: a host at another baud
than the bus's gets no answer, as on a real RS-485 line.

The servos run their profiles on the simulation's clock. With a ``SimWorld(mode="realtime")``
that is the wall clock; in lockstep mode the joints move only while someone advances the world
(the driver's ``sleep`` hook does, see :func:`armvision.bench.system.sim_system`).
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import select
import termios
import threading
import time
import tty
from dataclasses import dataclass, field

import numpy as np

from armvision.robot import xseries as xs
from armvision.sim.model import GRIPPER_MAX_FORCE_N
from armvision.sim.world import SimWorld

log = logging.getLogger("armvision.sim")

# Instructions (e-manual, Protocol 2.0).
PING, READ, WRITE, REG_WRITE, ACTION, FACTORY_RESET, REBOOT, CLEAR = 1, 2, 3, 4, 5, 6, 8, 0x10
STATUS, SYNC_READ, SYNC_WRITE, BULK_READ, BULK_WRITE = 0x55, 0x82, 0x83, 0x92, 0x93
BROADCAST_ID = 0xFE
HEADER = b"\xff\xff\xfd\x00"


def crc16(data: bytes | bytearray, crc: int = 0) -> int:
    """Protocol 2.0 CRC-16: polynomial x^16 + x^15 + x^2 + 1 (0x8005), initial 0, MSB first,
    over the packet from the header to the last parameter (e-manual "CRC calculation")."""
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def stuff(payload: bytes) -> bytes:
    """Byte stuffing: after every FF FF FD in the instruction/parameters insert an FD."""
    out = bytearray()
    for b in payload:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(payload: bytes) -> bytes:
    """Undo :func:`stuff`: FF FF FD FD -> FF FF FD."""
    out = bytearray()
    i = 0
    while i < len(payload):
        b = payload[i]
        out.append(b)
        if (
            b == 0xFD
            and len(out) >= 3
            and out[-3] == 0xFF
            and out[-2] == 0xFF
            and i + 1 < len(payload)
            and payload[i + 1] == 0xFD
        ):
            i += 1  # drop the stuffed FD
        i += 1
    return bytes(out)


def packet(dxl_id: int, instruction: int, params: bytes = b"") -> bytes:
    """A whole Protocol 2.0 packet: header, ID, length, stuffed body, CRC."""
    body = stuff(bytes([instruction]) + params)
    length = len(body) + 2
    head = HEADER + bytes([dxl_id, length & 0xFF, length >> 8])
    crc = crc16(head + body)
    return head + body + bytes([crc & 0xFF, crc >> 8])


def status_packet(dxl_id: int, error: int, params: bytes = b"") -> bytes:
    return packet(dxl_id, STATUS, bytes([error]) + params)


@dataclass
class _Profile:
    """A servo's motion profile in joint terms (rad), sampled on simulation time."""

    q_start: float
    q_goal: float
    t0: float
    duration: float
    accel: float

    def sample(self, t: float) -> tuple[float, float]:
        T, ta = self.duration, self.accel
        d = self.q_goal - self.q_start
        if T <= 0.0:
            return self.q_goal, 0.0
        v = d / (T - ta)
        s = min(max(t - self.t0, 0.0), T)
        if ta > 0.0 and s < ta:
            return self.q_start + v * 0.5 * s * s / ta, v * s / ta
        if s <= T - ta:
            return self.q_start + v * (s - 0.5 * ta), v
        r = T - s
        return self.q_start + v * ((T - ta) - (0.5 * r * r / ta if ta > 0 else 0.0)), (
            v * r / ta if ta > 0 else 0.0
        )


@dataclass
class EmulatedServo:
    """One servo: its control table and how it sits on the arm."""

    spec: xs.BusServo
    #: +1 if the horn turns with the joint, -1 if mounted mirror-image (a reversed master).
    mount: int
    table: bytearray = field(default_factory=lambda: bytearray(xs.TABLE_SIZE))
    silent: bool = False
    corrupt: bool = False
    delay_s: float = 0.0
    registered: tuple[int, bytes] | None = None

    def get(self, reg: tuple[int, int]) -> int:
        addr, size = reg
        return int.from_bytes(self.table[addr : addr + size], "little", signed=addr in xs.SIGNED)

    def put(self, reg: tuple[int, int], value: int) -> None:
        addr, size = reg
        signed = addr in xs.SIGNED
        self.table[addr : addr + size] = int(value).to_bytes(size, "little", signed=signed)

    @property
    def sign(self) -> int:
        """Register direction x mount: +1 when ticks grow with the joint angle."""
        reverse = self.get(xs.DRIVE_MODE) & xs.DRIVE_MODE_REVERSE
        return (-1 if reverse else 1) * self.mount


def _factory_table(spec: xs.BusServo) -> bytearray:
    s = EmulatedServo(spec, 1)
    m = spec.model
    for reg, value in (
        (xs.MODEL_NUMBER, m.number),
        (xs.FIRMWARE_VERSION, 48),
        (xs.ID, spec.id),
        (xs.BAUD_RATE, 3),
        (xs.RETURN_DELAY_TIME, 0),
        (xs.DRIVE_MODE, xs.DRIVE_MODE_REVERSE if spec.reverse else 0),
        (xs.OPERATING_MODE, xs.OPERATING_MODE_POSITION),
        (xs.SECONDARY_ID, spec.secondary_id),
        (xs.PROTOCOL_TYPE, 2),
        (xs.MOVING_THRESHOLD, 10),
        (xs.TEMPERATURE_LIMIT, 80),
        (xs.MAX_VOLTAGE_LIMIT, 160),
        (xs.MIN_VOLTAGE_LIMIT, 95),
        (xs.PWM_LIMIT, 885),
        (xs.CURRENT_LIMIT, m.current_limit),
        (xs.VELOCITY_LIMIT, 131),
        (xs.MAX_POSITION_LIMIT, spec.max_tick),
        (xs.MIN_POSITION_LIMIT, spec.min_tick),
        (xs.SHUTDOWN, 52),
        (xs.STATUS_RETURN_LEVEL, 2),
        (xs.VELOCITY_I_GAIN, 1920),
        (xs.VELOCITY_P_GAIN, 100),
        (xs.POSITION_P_GAIN, 800),
        (xs.GOAL_PWM, 885),
        (xs.GOAL_CURRENT, m.current_limit),
        (xs.GOAL_VELOCITY, 0),
        (xs.PRESENT_INPUT_VOLTAGE, 120),
        (xs.PRESENT_TEMPERATURE, 30),
    ):
        s.put(reg, value)
    return s.table


class ServoBusEmulator:
    """The vx300s servo bus on a pty, answering from ``world`` (see the module docstring).

    ``start()`` (or ``with``) opens the pty and the thread; ``port`` is the path to open.
    ``baud_rate`` is what the servos' Baud_Rate register says (vx300s: 1 Mbps).
    """

    def __init__(self, world: SimWorld, baud_rate: int = xs.VX300S_BAUD_RATE) -> None:
        self.world = world
        self.baud_rate = baud_rate
        self.servos = {
            spec.id: EmulatedServo(spec, -1 if spec.reverse else 1, _factory_table(spec))
            for spec in xs.VX300S_BUS
        }
        self._joint_index = {n: i for i, n in enumerate(world_joint_names())}
        self._profiles: dict[int, _Profile] = {}
        self._lock = threading.Lock()  # control tables and profiles
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._master_fd = self._slave_fd = -1
        self.port = ""
        self.packets = 0  # instruction packets handled, for the benchmark
        self.crc_errors = 0  # instruction packets that failed their CRC
        m, act = world.model, world.arm_actuators
        # seconds: a position servo lags by kv/kp x velocity (SimArm's feed-forward)
        self._lead = -m.actuator_biasprm[act, 2] / m.actuator_gainprm[act, 0]
        self._gain = m.actuator_gainprm[act, 0].copy()
        self._bias = m.actuator_biasprm[act].copy()
        self._ctrl_lo = m.actuator_ctrlrange[act, 0].copy()
        self._ctrl_hi = m.actuator_ctrlrange[act, 1].copy()
        g = world.gripper_actuator
        self._gripper_gain = float(m.actuator_gainprm[g, 0])
        self._gripper_bias = m.actuator_biasprm[g].copy()
        self._torque = [True] * 7  # per joint (6 arm + gripper), what the physics sees
        with world.lock:
            q = world.data.qpos[world._qadr].copy()
            finger = float(world.data.qpos[world._finger_qadr[0]])
            for servo in self.servos.values():
                # As Interbotix's xs_sdk leaves the arm: time-based profiles, torque on, the
                # gripper in PWM mode.
                servo.put(xs.DRIVE_MODE, servo.get(xs.DRIVE_MODE) | xs.DRIVE_MODE_TIME_BASED)
                if servo.spec.joint == "gripper":
                    servo.put(xs.OPERATING_MODE, xs.OPERATING_MODE_PWM)
                servo.put(xs.TORQUE_ENABLE, 1)
                servo.put(xs.GOAL_POSITION, self._present_tick(servo, q, finger))
            world.data.ctrl[act] = q  # hold where the arm is
        self._hold = q.copy()
        self._apply_torque()
        world.add_controller(self._control)

    # ---------------------------------------------------------------- lifecycle

    def start(self) -> ServoBusEmulator:
        self._master_fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)
        self.port = os.ttyname(self._slave_fd)
        self._thread = threading.Thread(target=self._serve, name="servo-bus", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for fd in (self._master_fd, self._slave_fd):
            if fd >= 0:
                os.close(fd)
        self._master_fd = self._slave_fd = -1
        with contextlib.suppress(ValueError):
            self.world.remove_controller(self._control)

    def __enter__(self) -> ServoBusEmulator:
        return self.start() if self._thread is None else self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- faults

    def silence(self, dxl_id: int, silent: bool = True) -> None:
        """The servo stops answering and holding (its cable carries the power too)."""
        with self._lock:
            self.servos[dxl_id].silent = silent
            self._apply_torque()

    def corrupt_crc(self, dxl_id: int, corrupt: bool = True) -> None:
        """Every status packet from ``dxl_id`` carries a wrong CRC (noise on the line)."""
        self.servos[dxl_id].corrupt = corrupt

    def delay(self, dxl_id: int, seconds: float) -> None:
        """``dxl_id`` answers ``seconds`` late (0: on time), past the host's packet timeout."""
        self.servos[dxl_id].delay_s = float(seconds)

    def set_hardware_error(self, dxl_id: int, bits: int) -> None:
        """Raise Hardware_Error_Status bits; those in Shutdown turn the torque off, as the
        firmware does. Only a reboot clears them."""
        with self._lock:
            servo = self.servos[dxl_id]
            servo.put(xs.HARDWARE_ERROR_STATUS, servo.get(xs.HARDWARE_ERROR_STATUS) | bits)
            if bits & servo.get(xs.SHUTDOWN):
                servo.put(xs.TORQUE_ENABLE, 0)
            self._apply_torque()

    def set_input_voltage(self, volts: float) -> None:
        """The supply voltage every servo sees; below Min_Voltage_Limit (9.5 V) or above the
        max sets the input voltage error bit."""
        with self._lock:
            for servo in self.servos.values():
                servo.put(xs.PRESENT_INPUT_VOLTAGE, round(volts / xs.VOLT_PER_LSB))
                lo, hi = servo.get(xs.MIN_VOLTAGE_LIMIT), servo.get(xs.MAX_VOLTAGE_LIMIT)
                if not lo <= servo.get(xs.PRESENT_INPUT_VOLTAGE) <= hi:
                    servo.put(xs.HARDWARE_ERROR_STATUS, servo.get(xs.HARDWARE_ERROR_STATUS) | 1)
                    if servo.get(xs.SHUTDOWN) & 1:
                        servo.put(xs.TORQUE_ENABLE, 0)
            self._apply_torque()

    # ---------------------------------------------------------------- physics side

    def _servos_of(self, joint: str) -> list[EmulatedServo]:
        return [s for s in self.servos.values() if s.spec.joint == joint]

    def _present_tick(self, servo: EmulatedServo, q: np.ndarray, finger: float = 0.0) -> int:
        if servo.spec.joint == "gripper":
            theta = xs.motor_angle_from_finger(finger)
        else:
            theta = float(q[self._joint_index[servo.spec.joint]])
        return xs.rad_to_tick(servo.sign * theta)

    def _joint_goal(self, servo: EmulatedServo) -> float:
        """The servo's Goal_Position as a joint angle (gripper: finger travel, m)."""
        theta = servo.sign * xs.tick_to_rad(servo.get(xs.GOAL_POSITION))
        if servo.spec.joint == "gripper":
            return xs.finger_from_motor_angle(theta)
        return theta

    def _start_profile(self, servo: EmulatedServo) -> None:
        """A new Goal_Position: plan the servo's profile from where its last one is now. A
        shadow plans it too (it got the same write), so it drives the joint on its own when its
        master's torque is off."""
        if servo.spec.joint == "gripper":
            self._command_gripper(servo)
            return
        j = self._joint_index[servo.spec.joint]
        t = self.world.time
        old = self._profiles.get(j)
        q_start = old.sample(t)[0] if old is not None else float(self._hold[j])
        pv, pa = servo.get(xs.PROFILE_VELOCITY), servo.get(xs.PROFILE_ACCELERATION)
        goal = self._joint_goal(servo)
        if servo.get(xs.DRIVE_MODE) & xs.DRIVE_MODE_TIME_BASED:
            duration, accel = pv / 1000.0, pa / 1000.0
        elif pv > 0:  # velocity-based: rev/min and rev/min^2 units
            v = pv * xs.RAD_S_PER_VELOCITY_LSB
            a = pa * 214.577 * 2.0 * math.pi / 3600.0 if pa > 0 else math.inf
            accel = v / a
            duration = abs(goal - q_start) / v + accel
        else:
            duration, accel = 0.0, 0.0
        accel = min(accel, duration / 2.0)
        self._profiles[j] = _Profile(q_start, goal, t, duration, accel)

    def _command_gripper(self, servo: EmulatedServo) -> None:
        with self.world.lock:
            self.world.data.ctrl[self.world.gripper_actuator] = self._joint_goal(servo)
            mode = servo.get(xs.OPERATING_MODE)
            limit = max(servo.get(xs.CURRENT_LIMIT), 1)
            if mode == xs.OPERATING_MODE_CURRENT_BASED_POSITION:
                share = min(abs(servo.get(xs.GOAL_CURRENT)), limit) / limit
            else:
                share = 1.0
            force = max(GRIPPER_MAX_FORCE_N * share, 0.05)
            self.world.model.actuator_forcerange[self.world.gripper_actuator] = [-force, force]

    def _apply_torque(self) -> None:
        """Torque off makes a joint limp (no servo gains); a joint is held while either its
        master or its shadow has torque on (both lift the shoulder on the real arm)."""
        m, act = self.world.model, self.world.arm_actuators
        with self.world.lock:
            for j, name in enumerate((*world_joint_names(), "gripper")):
                on = any(s.get(xs.TORQUE_ENABLE) and not s.silent for s in self._servos_of(name))
                if on and not self._torque[j] and j < 6:  # re-enabled: hold where it is now
                    q = float(self.world.data.qpos[self.world._qadr[j]])
                    self._hold[j] = q
                    self._profiles.pop(j, None)
                    self.world.data.ctrl[act[j]] = q
                self._torque[j] = on
                a = act[j] if j < 6 else self.world.gripper_actuator
                gain = self._gain[j] if j < 6 else self._gripper_gain
                bias = self._bias[j] if j < 6 else self._gripper_bias
                m.actuator_gainprm[a, 0] = gain if on else 0.0
                m.actuator_biasprm[a, 1] = bias[1] if on else 0.0
                m.actuator_biasprm[a, 2] = bias[2] if on else 0.0

    def _control(self, t: float) -> None:
        """World controller (under the world's lock): feed each profile to its servo."""
        ctrl = self.world.data.ctrl
        for j, profile in list(self._profiles.items()):
            q, qd = profile.sample(t)
            if t - profile.t0 >= profile.duration:
                del self._profiles[j]
                q, qd = profile.q_goal, 0.0
            self._hold[j] = q
            a = self.world.arm_actuators[j]
            ctrl[a] = min(max(q + self._lead[j] * qd, self._ctrl_lo[j]), self._ctrl_hi[j])

    def _refresh_present(self) -> None:
        """Copy the simulation into every servo's Present_* registers (under self._lock)."""
        w = self.world
        # No world lock: the realtime physics thread, when it runs behind, takes the lock back
        # as soon as it lets it go, and a servo must answer within the host's packet timeout.
        # The copies below are of one state, give or take the step being computed.
        d = w.data
        q = d.qpos[w._qadr].copy()
        qd = d.qvel[w._dofadr].copy()
        # The model compensates gravity on the arm's links (gravcomp) instead of loading
        # the actuators: on the real arm the motors hold that weight, so it is in the torque.
        torque_on = np.array(self._torque[:6], dtype=float)
        tau = (d.actuator_force[w.arm_actuators] + d.qfrc_gravcomp[w._dofadr]) * torque_on
        finger = float(d.qpos[w._finger_qadr[0]])
        finger_force = float(d.actuator_force[w.gripper_actuator])
        tick_ms = int(d.time * 1000.0) % 32768
        for servo in self.servos.values():
            spec = servo.spec
            servo.put(xs.PRESENT_POSITION, self._present_tick(servo, q, finger))
            servo.put(xs.REALTIME_TICK, tick_ms)
            if spec.joint == "gripper":
                limit = max(servo.get(xs.CURRENT_LIMIT), 1)
                # the force model of _command_gripper, backwards: full force = Current_Limit
                current = -finger_force / GRIPPER_MAX_FORCE_N * limit
                servo.put(xs.PRESENT_CURRENT, round(current))
                servo.put(xs.PRESENT_VELOCITY, 0)
                continue
            j = self._joint_index[spec.joint]
            share = len(self._servos_of(spec.joint))
            amps = servo.sign * tau[j] / share / spec.model.torque_per_amp
            servo.put(xs.PRESENT_CURRENT, round(amps / xs.CURRENT_A_PER_LSB))
            servo.put(xs.PRESENT_VELOCITY, round(servo.sign * qd[j] / xs.RAD_S_PER_VELOCITY_LSB))
            moving = j in self._profiles or abs(qd[j]) > 10 * xs.RAD_S_PER_VELOCITY_LSB
            servo.put(xs.MOVING, int(moving))

    # ---------------------------------------------------------------- the wire

    def _host_baud(self) -> int:
        """The baud rate the host set on its end of the line (termios of the pty slave)."""
        try:
            speed = termios.tcgetattr(self._slave_fd)[5]
        except termios.error:
            return self.baud_rate
        return _SPEEDS.get(speed, -1)

    def _serve(self) -> None:
        buf = bytearray()
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master_fd], [], [], 0.05)
            if not ready:
                continue
            try:
                chunk = os.read(self._master_fd, 4096)
            except OSError:  # the host closed the port: wait for it to open again
                time.sleep(0.01)
                continue
            if self._host_baud() != self.baud_rate:
                continue  # framing errors on a real line: the servos hear garbage
            buf.extend(chunk)
            try:
                self._drain(buf)
            except Exception:  # a bug here must not kill the bus silently
                log.exception("servo-bus emulator failed on a packet")
                buf.clear()

    def _drain(self, buf: bytearray) -> None:
        """Handle every whole packet at the front of ``buf``."""
        while True:
            start = buf.find(HEADER[:3])
            if start < 0:
                del buf[:-2]
                return
            del buf[:start]
            if len(buf) < 7:
                return
            length = buf[5] | buf[6] << 8
            total = 7 + length
            if length < 3 or length > 1024:
                del buf[:3]
                continue
            if len(buf) < total:
                return
            raw = bytes(buf[:total])
            del buf[:total]
            self.packets += 1
            crc_ok = crc16(raw[:-2]) == (raw[-2] | raw[-1] << 8)
            body = unstuff(raw[7:-2])
            replies = self._handle(raw[4], body[0], body[1:], crc_ok)
            out = bytearray()
            for servo, data in replies:
                if servo.delay_s > 0.0:
                    threading.Timer(servo.delay_s, self._write, (data,)).start()
                    continue
                out += data
            if out:
                self._write(bytes(out))

    def _write(self, data: bytes) -> None:
        with contextlib.suppress(OSError):
            os.write(self._master_fd, data)

    # ---------------------------------------------------------------- instructions

    def _targets(self, dxl_id: int) -> list[EmulatedServo]:
        """Servos acting on a packet to ``dxl_id``: itself and the shadows listening to it."""
        if dxl_id == BROADCAST_ID:
            return [s for s in self.servos.values() if not s.silent]
        return [
            s
            for s in self.servos.values()
            if not s.silent and (s.spec.id == dxl_id or s.get(xs.SECONDARY_ID) == dxl_id)
        ]

    def _status(self, servo: EmulatedServo, error: int, params: bytes = b"") -> bytes:
        if servo.get(xs.HARDWARE_ERROR_STATUS):
            error |= xs.ERROR_ALERT
        data = status_packet(servo.spec.id, error, params)
        if servo.corrupt:
            data = data[:-2] + bytes([data[-2] ^ 0x5A, data[-1]])
        return data

    def _handle(
        self, dxl_id: int, inst: int, params: bytes, crc_ok: bool
    ) -> list[tuple[EmulatedServo, bytes]]:
        with self._lock:
            self._refresh_present()
            if not crc_ok:
                self.crc_errors += 1
                own = self.servos.get(dxl_id)
                if own is None or own.silent:
                    return []
                return [(own, self._status(own, 3))]
            if inst in (SYNC_READ, BULK_READ):
                return self._read_group(inst, params)
            if inst in (SYNC_WRITE, BULK_WRITE):
                self._write_group(inst, params)
                return []
            replies: list[tuple[EmulatedServo, bytes]] = []
            for servo in self._targets(dxl_id):
                # Only the addressed servo answers; shadows and broadcasts (but ping) do not.
                answers = servo.spec.id == dxl_id or (dxl_id == BROADCAST_ID and inst == PING)
                reply = self._one(servo, inst, params)
                if reply is not None and answers and servo.get(xs.STATUS_RETURN_LEVEL) > 0:
                    replies.append((servo, self._status(servo, *reply)))
            replies.sort(key=lambda r: r[0].spec.id)
            return replies

    def _one(self, servo: EmulatedServo, inst: int, params: bytes) -> tuple[int, bytes] | None:
        """Carry out one instruction on one servo: (error, params) of its status, or None."""
        if inst == PING:
            return 0, bytes(servo.table[0:3])
        if inst == READ:
            if len(params) != 4:
                return 5, b""
            addr, size = params[0] | params[1] << 8, params[2] | params[3] << 8
            if addr + size > xs.TABLE_SIZE:
                return 7, b""
            return 0, bytes(servo.table[addr : addr + size])
        if inst in (WRITE, REG_WRITE):
            if len(params) < 3:
                return 5, b""
            addr = params[0] | params[1] << 8
            if inst == REG_WRITE:
                servo.registered = (addr, params[2:])
                servo.table[xs.REGISTERED_INSTRUCTION[0]] = 1
                return 0, b""
            return self._write_table(servo, addr, params[2:]), b""
        if inst == ACTION:
            if servo.registered is not None:
                addr, data = servo.registered
                servo.registered = None
                servo.table[xs.REGISTERED_INSTRUCTION[0]] = 0
                self._write_table(servo, addr, data)
            return 0, b""
        if inst == REBOOT:
            self._reboot(servo)
            return 0, b""
        return 2, b""  # instruction error: factory reset, clear, ... are not emulated

    def _write_table(self, servo: EmulatedServo, addr: int, data: bytes) -> int:
        """Write ``data`` at ``addr`` with the firmware's checks; the status error number."""
        end = addr + len(data)
        if end > xs.TABLE_SIZE or any(a in xs.READ_ONLY for a in range(addr, end)):
            return 7
        if addr < xs.EEPROM_END and servo.get(xs.TORQUE_ENABLE):
            return 7  # EEPROM is locked while the torque is on
        old = bytes(servo.table[addr:end])
        servo.table[addr:end] = data
        goal_addr = xs.GOAL_POSITION[0]
        if addr <= goal_addr < end:
            goal = servo.get(xs.GOAL_POSITION)
            mode = servo.get(xs.OPERATING_MODE)
            lo, hi = servo.get(xs.MIN_POSITION_LIMIT), servo.get(xs.MAX_POSITION_LIMIT)
            if mode in (xs.OPERATING_MODE_POSITION, xs.OPERATING_MODE_CURRENT_BASED_POSITION) and (
                not lo <= goal <= hi
            ):
                servo.table[addr:end] = old
                return 6  # data limit error: outside Min/Max_Position_Limit
        torque_addr = xs.TORQUE_ENABLE[0]
        if addr <= torque_addr < end:
            if servo.get(xs.HARDWARE_ERROR_STATUS) & servo.get(xs.SHUTDOWN):
                servo.put(xs.TORQUE_ENABLE, 0)  # stays off until a reboot
            self._apply_torque()
        if addr <= goal_addr < end and servo.get(xs.TORQUE_ENABLE):
            self._start_profile(servo)
        return 0

    def _reboot(self, servo: EmulatedServo) -> None:
        """RAM back to its defaults (torque off, errors cleared unless still true)."""
        fresh = _factory_table(servo.spec)
        fresh[: xs.EEPROM_END] = servo.table[: xs.EEPROM_END]
        volts = servo.get(xs.PRESENT_INPUT_VOLTAGE)
        servo.table[:] = fresh
        servo.put(xs.PRESENT_INPUT_VOLTAGE, volts)
        lo, hi = servo.get(xs.MIN_VOLTAGE_LIMIT), servo.get(xs.MAX_VOLTAGE_LIMIT)
        if not lo <= volts <= hi:
            servo.put(xs.HARDWARE_ERROR_STATUS, 1)
        self._refresh_present()
        servo.put(xs.GOAL_POSITION, servo.get(xs.PRESENT_POSITION))
        self._apply_torque()

    def _read_group(self, inst: int, params: bytes) -> list[tuple[EmulatedServo, bytes]]:
        if inst == SYNC_READ:
            if len(params) < 5:
                return []
            addr, size = params[0] | params[1] << 8, params[2] | params[3] << 8
            requests = [(i, addr, size) for i in params[4:]]
        else:
            requests = [
                (params[k], params[k + 1] | params[k + 2] << 8, params[k + 3] | params[k + 4] << 8)
                for k in range(0, len(params) - 4, 5)
            ]
        replies = []
        for dxl_id, addr, size in requests:
            servo = self.servos.get(dxl_id)
            if servo is None or servo.silent:
                continue
            if addr + size > xs.TABLE_SIZE:
                replies.append((servo, self._status(servo, 7)))
            else:
                replies.append(
                    (servo, self._status(servo, 0, bytes(servo.table[addr : addr + size])))
                )
        return replies

    def _write_group(self, inst: int, params: bytes) -> None:
        if inst == SYNC_WRITE:
            if len(params) < 4:
                return
            addr, size = params[0] | params[1] << 8, params[2] | params[3] << 8
            rows = [
                (params[k], addr, params[k + 1 : k + 1 + size])
                for k in range(4, len(params) - size, size + 1)
            ]
        else:
            rows = []
            k = 0
            while k + 5 <= len(params):
                size = params[k + 3] | params[k + 4] << 8
                rows.append(
                    (params[k], params[k + 1] | params[k + 2] << 8, params[k + 5 : k + 5 + size])
                )
                k += 5 + size
        for dxl_id, addr, data in rows:
            for servo in self._targets(dxl_id):
                self._write_table(servo, addr, data)


def world_joint_names() -> tuple[str, ...]:
    from armvision.robot.kinematics import VX300S

    return tuple(VX300S.joint_names)


_SPEEDS = {
    getattr(termios, f"B{rate}"): rate
    for rate in (
        9600,
        19200,
        38400,
        57600,
        115200,
        230400,
        460800,
        500000,
        576000,
        921600,
        1000000,
        1152000,
        2000000,
        2500000,
        3000000,
        3500000,
        4000000,
    )
    if hasattr(termios, f"B{rate}")
}
