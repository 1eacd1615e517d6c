"""ODrive "CAN Simple" message codec for ODrive v3.6 firmware 0.5.x (pure: bytes in, values out, no I/O).

Written by this project from ODrive's protocol documentation (docs/can-protocol.rst and its message table
for firmware 0.5.x, plus the 0.5.6 release notes); verified in tests against the firmware's own DBC file
with cantools.

Frame layout
    * 11-bit arbitration id = ``node_id << 5 | cmd_id`` (node 0..63); 29-bit ids work the same way with
      node ids up to 0xFFFFFF when the axis uses ``can.is_extended``.
    * All values little endian; floats are IEEE 754 float32.
    * "Get" messages (heartbeat aside) are answered when the host sends the same id with the RTR bit set
      (firmware >= 0.5.5 also answers a data frame with DLC 0). Every frame addressed to an axis feeds that
      axis' watchdog.

Supported messages (cmd id): Heartbeat (0x01), Estop (0x02), Get_Motor_Error (0x03, 64-bit in the firmware
though the DBC declares 32), Get_Encoder_Error (0x04), Set_Axis_Node_ID (0x06), Set_Axis_State (0x07),
Get_Encoder_Estimates (0x09), Set_Controller_Mode (0x0B), Set_Input_Vel (0x0D), Set_Limits (0x0F),
Get_Iq (0x14), Reboot (0x16), Get_Bus_Voltage_Current (0x17), Clear_Errors (0x18),
Get_Controller_Error (0x1D). Any other command id, a short payload or an impossible id raises
:class:`CanParseError` — the only exception :func:`parse_frame` raises.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, fields
from enum import IntEnum, IntFlag
from typing import ClassVar

import can

from beambench.common.errors import BeambenchError

CMD_BITS = 5
CMD_MASK = (1 << CMD_BITS) - 1
MAX_NODE_ID = 0x3F
MAX_NODE_ID_EXTENDED = 0xFFFFFF


class CanParseError(BeambenchError, ValueError):
    """A CAN frame is not a well-formed CAN Simple message this codec knows."""


class Cmd(IntEnum):
    """CAN Simple command ids (firmware 0.5.x)."""

    CANOPEN_NMT = 0x00  # reserved for CANopen, not CAN Simple
    HEARTBEAT = 0x01
    ESTOP = 0x02
    GET_MOTOR_ERROR = 0x03
    GET_ENCODER_ERROR = 0x04
    GET_SENSORLESS_ERROR = 0x05
    SET_AXIS_NODE_ID = 0x06
    SET_AXIS_STATE = 0x07
    SET_AXIS_STARTUP_CONFIG = 0x08  # not implemented by the firmware
    GET_ENCODER_ESTIMATES = 0x09
    GET_ENCODER_COUNT = 0x0A
    SET_CONTROLLER_MODE = 0x0B
    SET_INPUT_POS = 0x0C
    SET_INPUT_VEL = 0x0D
    SET_INPUT_TORQUE = 0x0E
    SET_LIMITS = 0x0F
    START_ANTICOGGING = 0x10
    SET_TRAJ_VEL_LIMIT = 0x11
    SET_TRAJ_ACCEL_LIMITS = 0x12
    SET_TRAJ_INERTIA = 0x13
    GET_IQ = 0x14
    GET_SENSORLESS_ESTIMATES = 0x15
    REBOOT = 0x16
    GET_BUS_VOLTAGE_CURRENT = 0x17
    CLEAR_ERRORS = 0x18
    SET_LINEAR_COUNT = 0x19
    SET_POS_GAIN = 0x1A
    SET_VEL_GAINS = 0x1B
    GET_ADC_VOLTAGE = 0x1C
    GET_CONTROLLER_ERROR = 0x1D


class AxisState(IntEnum):
    UNDEFINED = 0
    IDLE = 1
    STARTUP_SEQUENCE = 2
    FULL_CALIBRATION_SEQUENCE = 3
    MOTOR_CALIBRATION = 4
    ENCODER_INDEX_SEARCH = 6
    ENCODER_OFFSET_CALIBRATION = 7
    CLOSED_LOOP_CONTROL = 8
    LOCKIN_SPIN = 9
    ENCODER_DIR_FIND = 10
    HOMING = 11
    ENCODER_HALL_POLARITY_CALIBRATION = 12
    ENCODER_HALL_PHASE_CALIBRATION = 13


class ControlMode(IntEnum):
    VOLTAGE_CONTROL = 0
    TORQUE_CONTROL = 1
    VELOCITY_CONTROL = 2
    POSITION_CONTROL = 3


class InputMode(IntEnum):
    INACTIVE = 0
    PASSTHROUGH = 1
    VEL_RAMP = 2
    POS_FILTER = 3
    MIX_CHANNELS = 4
    TRAP_TRAJ = 5
    TORQUE_RAMP = 6
    MIRROR = 7
    TUNING = 8


class AxisError(IntFlag):
    """``axis.error`` bits of firmware 0.5.x."""

    NONE = 0
    INVALID_STATE = 0x1
    MOTOR_FAILED = 0x40
    SENSORLESS_ESTIMATOR_FAILED = 0x80
    ENCODER_FAILED = 0x100
    CONTROLLER_FAILED = 0x200
    WATCHDOG_TIMER_EXPIRED = 0x800
    MIN_ENDSTOP_PRESSED = 0x1000
    MAX_ENDSTOP_PRESSED = 0x2000
    ESTOP_REQUESTED = 0x4000
    HOMING_WITHOUT_ENDSTOP = 0x20000
    OVER_TEMP = 0x40000
    UNKNOWN_POSITION = 0x80000


class ControllerError(IntFlag):
    NONE = 0
    OVERSPEED = 0x1
    INVALID_INPUT_MODE = 0x2
    UNSTABLE_GAIN = 0x4
    INVALID_MIRROR_AXIS = 0x8
    INVALID_LOAD_ENCODER = 0x10
    INVALID_ESTIMATE = 0x20
    INVALID_CIRCULAR_RANGE = 0x40
    SPINOUT_DETECTED = 0x80


def error_names(bits: int, flags: type[IntFlag] = AxisError) -> str:
    """``"WATCHDOG_TIMER_EXPIRED|ESTOP_REQUESTED"`` for known bits, hex for the rest; ``"NONE"`` for 0."""
    if bits == 0:
        return "NONE"
    names = [f.name for f in flags if f.value and bits & f.value == f.value and f.name]
    rest = bits & ~sum(f.value for f in flags)
    if rest:
        names.append(hex(rest))
    return "|".join(names)


# ---------------------------------------------------------------------------------------------- ids


def arbitration_id(node_id: int, cmd: int, extended: bool = False) -> int:
    """``node_id << 5 | cmd``; raises ValueError for a node or command id out of range."""
    limit = MAX_NODE_ID_EXTENDED if extended else MAX_NODE_ID
    if not 0 <= node_id <= limit:
        raise ValueError(f"node_id {node_id} out of range 0..{limit}")
    if not 0 <= cmd <= CMD_MASK:
        raise ValueError(f"cmd_id {cmd} out of range 0..{CMD_MASK}")
    return node_id << CMD_BITS | cmd


def split_id(arb_id: int, extended: bool = False) -> tuple[int, int]:
    """(node_id, cmd_id) of an arbitration id; CanParseError if it does not fit 11 (or 29) bits."""
    limit = 0x1FFFFFFF if extended else 0x7FF
    if not 0 <= arb_id <= limit:
        raise CanParseError(f"arbitration id {arb_id:#x} does not fit {'29' if extended else '11'} bits")
    return arb_id >> CMD_BITS, arb_id & CMD_MASK


# ------------------------------------------------------------------------------------------ messages


_STRUCTS: dict[str, struct.Struct] = {}


@dataclass(frozen=True)
class _Msg:
    """A CAN Simple payload: ``FORMAT`` is the struct layout of its fields in declaration order."""

    CMD: ClassVar[Cmd]
    FORMAT: ClassVar[str] = "<"
    DLC: ClassVar[int] = 8  # what the firmware puts on the wire
    IS_GET: ClassVar[bool] = False  # may be requested by RTR

    def values(self) -> tuple:
        return tuple(getattr(self, f.name) for f in fields(self))

    def encode(self) -> bytes:
        """Payload bytes, padded with zeros to ``DLC``. ValueError for out-of-range or non-finite values."""
        vals = self.values()
        for f, v in zip(fields(self), vals):
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"{type(self).__name__}.{f.name} = {v!r} is not finite")
        try:
            body = struct.pack(self.FORMAT, *vals)
        except struct.error as exc:
            raise ValueError(f"{type(self).__name__}{vals}: {exc}") from None
        return body.ljust(self.DLC, b"\0")

    @classmethod
    def decode(cls, data: bytes) -> _Msg:
        layout = _STRUCTS.get(cls.FORMAT) or _STRUCTS.setdefault(cls.FORMAT, struct.Struct(cls.FORMAT))
        if len(data) < layout.size:
            raise CanParseError(f"{cls.__name__}: payload has {len(data)} bytes, needs {layout.size}")
        return cls(*layout.unpack_from(data))


@dataclass(frozen=True)
class Heartbeat(_Msg):
    """Cyclic status (default every 100 ms). The flag bytes were added in firmware 0.5.6."""

    CMD = Cmd.HEARTBEAT
    IS_GET = False  # the 0.5.x firmware ignores a heartbeat RTR
    axis_error: int = 0
    axis_state: int = AxisState.IDLE
    motor_error_flag: bool = False
    encoder_error_flag: bool = False
    controller_error_flag: bool = False
    trajectory_done: bool = False

    def encode(self) -> bytes:
        try:
            head = struct.pack("<IB", self.axis_error, self.axis_state)
        except struct.error as exc:
            raise ValueError(f"Heartbeat: {exc}") from None
        last = int(bool(self.controller_error_flag)) | int(bool(self.trajectory_done)) << 7
        return head + bytes([int(bool(self.motor_error_flag)), int(bool(self.encoder_error_flag)), last])

    @classmethod
    def decode(cls, data: bytes) -> Heartbeat:
        if len(data) < 5:
            raise CanParseError(f"Heartbeat: payload has {len(data)} bytes, needs 5")
        err, state = struct.unpack_from("<IB", data)
        b = bytes(data[5:8]).ljust(3, b"\0")  # firmware < 0.5.6 left the flags out
        return cls(err, state, bool(b[0] & 1), bool(b[1] & 1), bool(b[2] & 1), bool(b[2] & 0x80))


@dataclass(frozen=True)
class Estop(_Msg):
    """Host → axis: sets ``ESTOP_REQUESTED``; the axis goes idle until errors are cleared."""

    CMD = Cmd.ESTOP
    DLC = 0


@dataclass(frozen=True)
class MotorError(_Msg):
    CMD = Cmd.GET_MOTOR_ERROR
    FORMAT = "<Q"
    IS_GET = True
    error: int = 0

    @classmethod
    def decode(cls, data: bytes) -> MotorError:
        if len(data) >= 8:
            return cls(struct.unpack_from("<Q", data)[0])
        if len(data) >= 4:  # the DBC declares only the low 32 bits
            return cls(struct.unpack_from("<I", data)[0])
        raise CanParseError(f"MotorError: payload has {len(data)} bytes, needs 4")


@dataclass(frozen=True)
class EncoderError(_Msg):
    CMD = Cmd.GET_ENCODER_ERROR
    FORMAT = "<I"
    IS_GET = True
    error: int = 0


@dataclass(frozen=True)
class ControllerErrorMsg(_Msg):
    CMD = Cmd.GET_CONTROLLER_ERROR
    FORMAT = "<I"
    IS_GET = True
    error: int = 0


@dataclass(frozen=True)
class SetAxisNodeId(_Msg):
    CMD = Cmd.SET_AXIS_NODE_ID
    FORMAT = "<I"
    node_id: int = 0


@dataclass(frozen=True)
class SetAxisState(_Msg):
    CMD = Cmd.SET_AXIS_STATE
    FORMAT = "<I"
    state: int = AxisState.IDLE


@dataclass(frozen=True)
class EncoderEstimates(_Msg):
    """Cyclic (default every 10 ms): position in turns, velocity in turn/s."""

    CMD = Cmd.GET_ENCODER_ESTIMATES
    FORMAT = "<ff"
    IS_GET = True
    pos: float = 0.0
    vel: float = 0.0


@dataclass(frozen=True)
class SetControllerMode(_Msg):
    CMD = Cmd.SET_CONTROLLER_MODE
    FORMAT = "<ii"
    control_mode: int = ControlMode.VELOCITY_CONTROL
    input_mode: int = InputMode.VEL_RAMP


@dataclass(frozen=True)
class SetInputVel(_Msg):
    """Velocity setpoint in turn/s and torque feed-forward in N·m."""

    CMD = Cmd.SET_INPUT_VEL
    FORMAT = "<ff"
    vel: float = 0.0
    torque_ff: float = 0.0


@dataclass(frozen=True)
class SetLimits(_Msg):
    """``controller.config.vel_limit`` (turn/s) and ``motor.config.current_lim`` (A)."""

    CMD = Cmd.SET_LIMITS
    FORMAT = "<ff"
    vel_limit: float = 2.0
    current_limit: float = 10.0


@dataclass(frozen=True)
class Iq(_Msg):
    CMD = Cmd.GET_IQ
    FORMAT = "<ff"
    IS_GET = True
    setpoint: float = 0.0
    measured: float = 0.0


@dataclass(frozen=True)
class Reboot(_Msg):
    CMD = Cmd.REBOOT
    DLC = 0


@dataclass(frozen=True)
class BusVoltageCurrent(_Msg):
    CMD = Cmd.GET_BUS_VOLTAGE_CURRENT
    FORMAT = "<ff"
    IS_GET = True
    voltage: float = 0.0
    current: float = 0.0


@dataclass(frozen=True)
class ClearErrors(_Msg):
    CMD = Cmd.CLEAR_ERRORS
    DLC = 0


@dataclass(frozen=True)
class Request:
    """An RTR "get" request (or a DLC-0 data frame, which firmware >= 0.5.5 answers the same way)."""

    cmd: Cmd


Message = (
    Heartbeat
    | Estop
    | MotorError
    | EncoderError
    | ControllerErrorMsg
    | SetAxisNodeId
    | SetAxisState
    | EncoderEstimates
    | SetControllerMode
    | SetInputVel
    | SetLimits
    | Iq
    | Reboot
    | BusVoltageCurrent
    | ClearErrors
)

MESSAGES: dict[Cmd, type[_Msg]] = {
    m.CMD: m
    for m in (
        Heartbeat,
        Estop,
        MotorError,
        EncoderError,
        ControllerErrorMsg,
        SetAxisNodeId,
        SetAxisState,
        EncoderEstimates,
        SetControllerMode,
        SetInputVel,
        SetLimits,
        Iq,
        Reboot,
        BusVoltageCurrent,
        ClearErrors,
    )
}
GET_CMDS = frozenset(c for c, m in MESSAGES.items() if m.IS_GET)
_BY_ID: dict[int, type[_Msg]] = {int(c): m for c, m in MESSAGES.items()}
_GET_IDS = frozenset(int(c) for c in GET_CMDS)


def decode(cmd: int, data: bytes) -> Message:
    """The message of command ``cmd`` carried in ``data``; CanParseError if unknown or too short."""
    if len(data) > 8:
        raise CanParseError(f"payload of {len(data)} bytes exceeds classic CAN's 8")
    cls = _BY_ID.get(cmd)
    if cls is None:
        raise CanParseError(f"command id {cmd:#04x} is not supported by this codec")
    return cls.decode(data)  # type: ignore[return-value]


def parse_frame(
    arb_id: int, data: bytes | bytearray, is_remote: bool = False, is_extended: bool = False
) -> tuple[int, Message | Request]:
    """(node_id, message) of a raw frame; a get request comes back as :class:`Request`.

    Raises only :class:`CanParseError`.
    """
    if type(data) is not bytes:
        try:
            data = bytes(data)
        except Exception as exc:
            raise CanParseError(f"payload is not bytes: {exc}") from None
    node, cmd = split_id(arb_id, is_extended)
    if is_remote or (not data and cmd in _GET_IDS):
        if cmd not in _GET_IDS:
            raise CanParseError(f"RTR for command id {cmd:#04x}, which is not a get message")
        return node, Request(Cmd(cmd))
    return node, decode(cmd, data)


def parse_message(msg: can.Message) -> tuple[int, Message | Request]:
    """:func:`parse_frame` of a python-can message (error frames are CanParseError too)."""
    if msg.is_error_frame:
        raise CanParseError("CAN error frame")
    return parse_frame(msg.arbitration_id, msg.data, msg.is_remote_frame, msg.is_extended_id)


def to_can(node_id: int, msg: Message, extended: bool = False) -> can.Message:
    """A python-can data frame carrying ``msg`` to or from ``node_id``."""
    data = msg.encode()
    return can.Message(
        arbitration_id=arbitration_id(node_id, msg.CMD, extended),
        data=data,
        dlc=len(data),
        is_extended_id=extended,
    )


def request(node_id: int, cmd: Cmd | type[_Msg], extended: bool = False) -> can.Message:
    """An RTR frame asking ``node_id`` for a get message (DLC 8, the size of the answer)."""
    c = Cmd(cmd.CMD if isinstance(cmd, type) else cmd)
    if c not in GET_CMDS:
        raise ValueError(f"{c.name} is not a get message")
    return can.Message(
        arbitration_id=arbitration_id(node_id, c, extended), is_remote_frame=True, dlc=8, is_extended_id=extended
    )


__all__ = [
    "AxisError",
    "AxisState",
    "BusVoltageCurrent",
    "CanParseError",
    "ClearErrors",
    "Cmd",
    "ControlMode",
    "ControllerError",
    "ControllerErrorMsg",
    "EncoderError",
    "EncoderEstimates",
    "Estop",
    "Heartbeat",
    "InputMode",
    "Iq",
    "Message",
    "MotorError",
    "Reboot",
    "Request",
    "SetAxisNodeId",
    "SetAxisState",
    "SetControllerMode",
    "SetInputVel",
    "SetLimits",
    "arbitration_id",
    "decode",
    "error_names",
    "parse_frame",
    "parse_message",
    "request",
    "split_id",
    "to_can",
]
