"""Facts of the Dynamixel X-series servos and of the ViperX-300s bus, with no SDK.

Control-table addresses, sizes and units are the ROBOTIS e-manual's for the XM430-W350 and
XM540-W270 (Protocol 2.0; the two share one table); the bus layout is Interbotix's
``interbotix_xsarm_control/config/vx300s.yaml``; the servo models are Trossen's vx300s
specification (XM540-W270 on waist, shoulder, elbow and forearm roll plus the two shadows and
the wrist angle, XM430-W350 on the wrist rotate and the gripper). The driver
(:mod:`armvision.robot.dynamixel`) and the bus emulator (:mod:`armvision.sim.servo_bus`) both
read them from here; the tests check them against the e-manual.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# ---------------------------------------------------------------- control table (address, size)
MODEL_NUMBER = (0, 2)
MODEL_INFORMATION = (2, 4)
FIRMWARE_VERSION = (6, 1)
ID = (7, 1)
BAUD_RATE = (8, 1)
RETURN_DELAY_TIME = (9, 1)
DRIVE_MODE = (10, 1)
OPERATING_MODE = (11, 1)
SECONDARY_ID = (12, 1)
PROTOCOL_TYPE = (13, 1)
HOMING_OFFSET = (20, 4)
MOVING_THRESHOLD = (24, 4)
TEMPERATURE_LIMIT = (31, 1)
MAX_VOLTAGE_LIMIT = (32, 2)
MIN_VOLTAGE_LIMIT = (34, 2)
PWM_LIMIT = (36, 2)
CURRENT_LIMIT = (38, 2)
VELOCITY_LIMIT = (44, 4)
MAX_POSITION_LIMIT = (48, 4)
MIN_POSITION_LIMIT = (52, 4)
STARTUP_CONFIGURATION = (60, 1)
SHUTDOWN = (63, 1)
TORQUE_ENABLE = (64, 1)
LED = (65, 1)
STATUS_RETURN_LEVEL = (68, 1)
REGISTERED_INSTRUCTION = (69, 1)
HARDWARE_ERROR_STATUS = (70, 1)
VELOCITY_I_GAIN = (76, 2)
VELOCITY_P_GAIN = (78, 2)
POSITION_D_GAIN = (80, 2)
POSITION_I_GAIN = (82, 2)
POSITION_P_GAIN = (84, 2)
FEEDFORWARD_2ND_GAIN = (88, 2)
FEEDFORWARD_1ST_GAIN = (90, 2)
BUS_WATCHDOG = (98, 1)
GOAL_PWM = (100, 2)
GOAL_CURRENT = (102, 2)
GOAL_VELOCITY = (104, 4)
PROFILE_ACCELERATION = (108, 4)
PROFILE_VELOCITY = (112, 4)
GOAL_POSITION = (116, 4)
REALTIME_TICK = (120, 2)
MOVING = (122, 1)
MOVING_STATUS = (123, 1)
PRESENT_PWM = (124, 2)
PRESENT_CURRENT = (126, 2)
PRESENT_VELOCITY = (128, 4)
PRESENT_POSITION = (132, 4)
VELOCITY_TRAJECTORY = (136, 4)
POSITION_TRAJECTORY = (140, 4)
PRESENT_INPUT_VOLTAGE = (144, 2)
PRESENT_TEMPERATURE = (146, 1)
#: One past the last address of the table above.
TABLE_SIZE = 147
#: Addresses below this are EEPROM: writable only with the torque off (else Access Error).
EEPROM_END = 64
#: Present_Current .. Present_Position: the block one sync read returns for the joint state.
STATE_BLOCK = (PRESENT_CURRENT[0], PRESENT_POSITION[0] + 4 - PRESENT_CURRENT[0])

#: Registers the host may not write (Access Error): read-only in the e-manual.
READ_ONLY = frozenset([*range(0, 7), *range(69, 71), *range(120, TABLE_SIZE)])
#: Signed registers (two's complement), by address.
SIGNED = frozenset(
    [HOMING_OFFSET[0], GOAL_PWM[0], GOAL_CURRENT[0], GOAL_VELOCITY[0], PRESENT_PWM[0],
     PRESENT_CURRENT[0], PRESENT_VELOCITY[0], PRESENT_POSITION[0], VELOCITY_TRAJECTORY[0],
     POSITION_TRAJECTORY[0]]
)  # fmt: skip

# ---------------------------------------------------------------- register values
OPERATING_MODE_CURRENT = 0
OPERATING_MODE_VELOCITY = 1
OPERATING_MODE_POSITION = 3
OPERATING_MODE_EXTENDED_POSITION = 4
OPERATING_MODE_CURRENT_BASED_POSITION = 5
OPERATING_MODE_PWM = 16

DRIVE_MODE_REVERSE = 0x01  # bit 0: positive direction is clockwise
DRIVE_MODE_TIME_BASED = 0x04  # bit 2: Profile_Velocity/Acceleration are times in ms

#: Hardware_Error_Status bits (e-manual), with what to tell the user.
HARDWARE_ERRORS = {
    0x01: "input voltage error (supply outside Min/Max_Voltage_Limit)",
    0x04: "overheating (above Temperature_Limit)",
    0x08: "motor encoder error",
    0x10: "electrical shock error (motor circuit)",
    0x20: "overload (load above the servo's torque for too long)",
}
#: Status-packet error field: bit 7 is the alert flag (a hardware error is set); 0-6 a number.
ERROR_ALERT = 0x80
STATUS_ERRORS = {
    1: "result fail",
    2: "instruction error",
    3: "CRC error",
    4: "data range error",
    5: "data length error",
    6: "data limit error",
    7: "access error",
}

#: Baud_Rate register value -> bps (e-manual).
BAUD_RATES = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000,
              6: 4_000_000, 7: 4_500_000}  # fmt: skip
FACTORY_BAUD_RATE = 57600

# ---------------------------------------------------------------- units
TICKS_PER_TURN = 4096
CENTRE_TICK = 2048  # 0 rad
RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_TURN
CURRENT_A_PER_LSB = 2.69e-3  # Present/Goal_Current, Current_Limit
VELOCITY_RPM_PER_LSB = 0.229  # Present/Goal_Velocity, Velocity_Limit, velocity-based profile
RAD_S_PER_VELOCITY_LSB = VELOCITY_RPM_PER_LSB * 2.0 * math.pi / 60.0
VOLT_PER_LSB = 0.1  # Present_Input_Voltage, voltage limits


def rad_to_tick(q: float) -> int:
    """Joint angle (rad, 0 at the centre) -> Goal/Present_Position ticks."""
    return round(CENTRE_TICK + q / RAD_PER_TICK)


def tick_to_rad(tick: int) -> float:
    return (tick - CENTRE_TICK) * RAD_PER_TICK


@dataclass(frozen=True)
class ServoModel:
    """One servo type: its model number and the factory defaults and limits that differ."""

    name: str
    number: int  # Model_Number
    current_limit: int  # Current_Limit factory default, 2.69 mA units
    velocity_limit: int  # Velocity_Limit factory default, 0.229 rpm units
    #: Torque constant, N·m per A: the e-manual's stall torque / stall current at 12 V.
    torque_per_amp: float


XM430_W350 = ServoModel("XM430-W350", 1020, 1193, 200, 4.1 / 2.3)
XM540_W270 = ServoModel("XM540-W270", 1120, 2047, 128, 10.6 / 4.4)


@dataclass(frozen=True)
class BusServo:
    """One servo on the arm's bus as Interbotix configures it (vx300s.yaml)."""

    name: str
    id: int
    model: ServoModel
    reverse: bool  # Drive_Mode bit 0
    min_tick: int
    max_tick: int
    secondary_id: int = 255  # 255: none; a shadow listens to its master's ID
    joint: str = ""  # the arm joint it drives ("gripper" for the gripper)

    @property
    def is_shadow(self) -> bool:
        return self.secondary_id != 255


VX300S_BUS = (
    BusServo("waist", 1, XM540_W270, False, 0, 4095, joint="waist"),
    BusServo("shoulder", 2, XM540_W270, True, 841, 2867, joint="shoulder"),
    BusServo("shoulder_shadow", 3, XM540_W270, False, 841, 2867, 2, joint="shoulder"),
    BusServo("elbow", 4, XM540_W270, True, 898, 3094, joint="elbow"),
    BusServo("elbow_shadow", 5, XM540_W270, False, 898, 3094, 4, joint="elbow"),
    BusServo("forearm_roll", 6, XM540_W270, False, 0, 4095, joint="forearm_roll"),
    BusServo("wrist_angle", 7, XM540_W270, True, 830, 3504, joint="wrist_angle"),
    BusServo("wrist_rotate", 8, XM430_W350, False, 0, 4095, joint="wrist_rotate"),
    BusServo("gripper", 9, XM430_W350, False, 0, 4095, joint="gripper"),
)
VX300S_BAUD_RATE = 1_000_000  # Baud_Rate 3

#: The gripper linkage (vx300s.yaml ``grippers.gripper``): horn radius and arm length, metres.
GRIPPER_HORN_RADIUS = 0.022
GRIPPER_ARM_LENGTH = 0.036


def finger_from_motor_angle(theta: float) -> float:
    """One finger's travel (m) from the gripper motor angle (rad), Interbotix's linkage formula:
    a1 = r sin(theta), c = sqrt(r^2 - a1^2), finger = a1 + sqrt(L^2 - c^2)."""
    r, L = GRIPPER_HORN_RADIUS, GRIPPER_ARM_LENGTH
    a1 = r * math.sin(theta)
    c2 = r * r - a1 * a1
    return a1 + math.sqrt(max(L * L - c2, 0.0))


def motor_angle_from_finger(finger: float) -> float:
    """Inverse of :func:`finger_from_motor_angle` on theta in [-pi/2, pi/2] (bisection; the
    formula increases monotonically there)."""
    lo, hi = -math.pi / 2.0, math.pi / 2.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if finger_from_motor_angle(mid) < finger:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def describe_hardware_error(bits: int) -> str:
    """Hardware_Error_Status as words, e.g. 'overload (...)'."""
    found = [text for bit, text in HARDWARE_ERRORS.items() if bits & bit]
    return "; ".join(found) if found else f"unknown hardware error bits 0x{bits:02x}"
