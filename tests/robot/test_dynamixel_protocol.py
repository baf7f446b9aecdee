"""Protocol 2.0 framing and the X-series facts, against ROBOTIS's documentation.

The packets are the worked examples of the e-manual's Protocol 2.0 page (ping, its status, read
of Present_Position, write of Goal_Position, broadcast ping), CRC included; the control-table
addresses are the e-manual's XM430-W350 / XM540-W270 table, typed in here by hand.
"""

from __future__ import annotations

import math
import random

import pytest

from armvision.robot import xseries as xs
from armvision.sim.servo_bus import (
    PING,
    READ,
    WRITE,
    crc16,
    packet,
    status_packet,
    stuff,
    unstuff,
)

# (packet, what it is) from the e-manual's Protocol 2.0 examples.
EMANUAL_PACKETS = [
    ("FF FF FD 00 01 03 00 01 19 4E", "ping ID 1"),
    ("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D", "ping status: model 1030, firmware 38"),
    ("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15", "read ID 1, address 132, 4 bytes"),
    ("FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89", "write ID 1, address 116, 512"),
    ("FF FF FD 00 FE 03 00 01 31 42", "broadcast ping"),
]


@pytest.mark.parametrize(("hex_packet", "what"), EMANUAL_PACKETS)
def test_crc16_matches_the_emanual_examples(hex_packet: str, what: str) -> None:
    raw = bytes.fromhex(hex_packet)
    assert crc16(raw[:-2]) == raw[-2] | raw[-1] << 8, what


def test_packets_are_built_as_in_the_emanual() -> None:
    assert packet(1, PING) == bytes.fromhex(EMANUAL_PACKETS[0][0])
    assert status_packet(1, 0, bytes([0x06, 0x04, 0x26])) == bytes.fromhex(EMANUAL_PACKETS[1][0])
    assert packet(1, READ, bytes([0x84, 0, 4, 0])) == bytes.fromhex(EMANUAL_PACKETS[2][0])
    write = packet(1, WRITE, bytes([0x74, 0]) + (512).to_bytes(4, "little"))
    assert write == bytes.fromhex(EMANUAL_PACKETS[3][0])
    assert packet(0xFE, PING) == bytes.fromhex(EMANUAL_PACKETS[4][0])


def test_crc16_agrees_with_the_sdks_table_implementation() -> None:
    sdk = pytest.importorskip("dynamixel_sdk")
    ph = sdk.PacketHandler(2.0)
    rng = random.Random(20)
    for _ in range(200):
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 80)))
        assert crc16(data) == ph.updateCRC(0, list(data), len(data))


def test_byte_stuffing_inserts_fd_after_ff_ff_fd_and_round_trips() -> None:
    # e-manual: instruction/parameters FF FF FD become FF FF FD FD; the length counts it.
    assert stuff(bytes.fromhex("03 FF FF FD 01")) == bytes.fromhex("03 FF FF FD FD 01")
    assert stuff(bytes.fromhex("FF FF FD FF FF FD")) == bytes.fromhex("FF FF FD FD FF FF FD FD")
    p = packet(1, WRITE, bytes([0x74, 0, 0xFF, 0xFF, 0xFD, 0x00]))
    length = p[5] | p[6] << 8
    assert length == len(p) - 7 and b"\xff\xff\xfd\xfd" in p[7:]
    rng = random.Random(3)
    for _ in range(300):
        body = bytes(rng.choice([0xFF, 0xFD, 0x00, rng.randrange(256)]) for _ in range(20))
        assert unstuff(stuff(body)) == body


def test_control_table_addresses_are_the_emanuals() -> None:
    emanual = {
        "MODEL_NUMBER": (0, 2), "FIRMWARE_VERSION": (6, 1), "ID": (7, 1), "BAUD_RATE": (8, 1),
        "RETURN_DELAY_TIME": (9, 1), "DRIVE_MODE": (10, 1), "OPERATING_MODE": (11, 1),
        "SECONDARY_ID": (12, 1), "PROTOCOL_TYPE": (13, 1), "HOMING_OFFSET": (20, 4),
        "TEMPERATURE_LIMIT": (31, 1), "MAX_VOLTAGE_LIMIT": (32, 2), "MIN_VOLTAGE_LIMIT": (34, 2),
        "PWM_LIMIT": (36, 2), "CURRENT_LIMIT": (38, 2), "VELOCITY_LIMIT": (44, 4),
        "MAX_POSITION_LIMIT": (48, 4), "MIN_POSITION_LIMIT": (52, 4), "SHUTDOWN": (63, 1),
        "TORQUE_ENABLE": (64, 1), "LED": (65, 1), "STATUS_RETURN_LEVEL": (68, 1),
        "HARDWARE_ERROR_STATUS": (70, 1), "POSITION_P_GAIN": (84, 2), "GOAL_CURRENT": (102, 2),
        "GOAL_VELOCITY": (104, 4), "PROFILE_ACCELERATION": (108, 4),
        "PROFILE_VELOCITY": (112, 4), "GOAL_POSITION": (116, 4), "MOVING": (122, 1),
        "PRESENT_CURRENT": (126, 2), "PRESENT_VELOCITY": (128, 4),
        "PRESENT_POSITION": (132, 4), "PRESENT_INPUT_VOLTAGE": (144, 2),
        "PRESENT_TEMPERATURE": (146, 1),
    }  # fmt: skip
    for name, reg in emanual.items():
        assert getattr(xs, name) == reg, name
    # One sync read covers current, velocity and position.
    assert xs.STATE_BLOCK == (126, 10)
    assert (xs.DRIVE_MODE_REVERSE, xs.DRIVE_MODE_TIME_BASED) == (1, 4)
    assert (xs.OPERATING_MODE_POSITION, xs.OPERATING_MODE_CURRENT_BASED_POSITION) == (3, 5)
    assert set(xs.HARDWARE_ERRORS) == {0x01, 0x04, 0x08, 0x10, 0x20}


def test_vx300s_bus_is_interbotix_s() -> None:
    by_name = {s.name: s for s in xs.VX300S_BUS}
    assert [s.id for s in xs.VX300S_BUS] == list(range(1, 10))
    assert {n for n, s in by_name.items() if s.reverse} == {"shoulder", "elbow", "wrist_angle"}
    assert by_name["shoulder_shadow"].secondary_id == 2
    assert by_name["elbow_shadow"].secondary_id == 4
    assert (by_name["shoulder"].min_tick, by_name["shoulder"].max_tick) == (841, 2867)
    assert (by_name["elbow"].min_tick, by_name["elbow"].max_tick) == (898, 3094)
    assert (by_name["wrist_angle"].min_tick, by_name["wrist_angle"].max_tick) == (830, 3504)
    assert {s.model.number for s in xs.VX300S_BUS if s.joint in ("wrist_rotate", "gripper")} == {
        1020
    }
    assert all(s.model.number == 1120 for s in xs.VX300S_BUS[:7])
    # Ticks: 4096 a turn, 2048 at 0 rad; the URDF's shoulder limit -1.85 rad is tick 842.
    assert xs.rad_to_tick(0.0) == 2048 and xs.rad_to_tick(math.pi / 2) == 3072
    assert xs.rad_to_tick(-1.850049) == 842


def test_gripper_linkage_is_interbotix_s_formula() -> None:
    r, L = 0.022, 0.036
    assert xs.finger_from_motor_angle(0.0) == pytest.approx(math.sqrt(L * L - r * r))
    assert xs.finger_from_motor_angle(math.pi / 2) == pytest.approx(r + L)
    for finger in (0.021, 0.035, 0.057):
        assert xs.finger_from_motor_angle(xs.motor_angle_from_finger(finger)) == pytest.approx(
            finger, abs=1e-9
        )
