"""CAN Simple codec: checked against the firmware's own DBC (cantools) in both directions, and fuzzed."""

from __future__ import annotations

import math
import struct
from datetime import timedelta

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from beambench.devices.odrive import cansimple as cs
from conftest import fuzz_examples, require_shared

f32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
u32 = st.integers(0, 2**32 - 1)
node = st.integers(0, 7)  # the DBC describes axes 0..7

# our message class, the DBC message name suffix, {our field: DBC signal}
MAPPING: dict[type, tuple[str, dict[str, str]]] = {
    cs.Heartbeat: (
        "Heartbeat",
        {
            "axis_error": "Axis_Error",
            "axis_state": "Axis_State",
            "motor_error_flag": "Motor_Error_Flag",
            "encoder_error_flag": "Encoder_Error_Flag",
            "controller_error_flag": "Controller_Error_Flag",
            "trajectory_done": "Trajectory_Done_Flag",
        },
    ),
    cs.MotorError: ("Get_Motor_Error", {"error": "Motor_Error"}),
    cs.EncoderError: ("Get_Encoder_Error", {"error": "Encoder_Error"}),
    cs.ControllerErrorMsg: ("Get_Controller_Error", {"error": "Controller_Error"}),
    cs.SetAxisNodeId: ("Set_Axis_Node_ID", {"node_id": "Axis_Node_ID"}),
    cs.SetAxisState: ("Set_Axis_State", {"state": "Axis_Requested_State"}),
    cs.EncoderEstimates: ("Get_Encoder_Estimates", {"pos": "Pos_Estimate", "vel": "Vel_Estimate"}),
    cs.SetControllerMode: ("Set_Controller_Mode", {"control_mode": "Control_Mode", "input_mode": "Input_Mode"}),
    cs.SetInputVel: ("Set_Input_Vel", {"vel": "Input_Vel", "torque_ff": "Input_Torque_FF"}),
    cs.SetLimits: ("Set_Limits", {"vel_limit": "Velocity_Limit", "current_limit": "Current_Limit"}),
    cs.Iq: ("Get_Iq", {"setpoint": "Iq_Setpoint", "measured": "Iq_Measured"}),
    cs.BusVoltageCurrent: ("Get_Bus_Voltage_Current", {"voltage": "Bus_Voltage", "current": "Bus_Current"}),
    cs.Reboot: ("Reboot", {}),
    cs.ClearErrors: ("Clear_Errors", {}),
}

messages = st.one_of(
    st.builds(cs.Heartbeat, u32, st.integers(0, 255), st.booleans(), st.booleans(), st.booleans(), st.booleans()),
    st.builds(cs.MotorError, u32),  # the DBC declares 32 bits (the firmware sends 64)
    st.builds(cs.EncoderError, u32),
    st.builds(cs.ControllerErrorMsg, u32),
    st.builds(cs.SetAxisNodeId, u32),
    st.builds(cs.SetAxisState, u32),
    st.builds(cs.EncoderEstimates, f32, f32),
    st.builds(cs.SetControllerMode, st.integers(0, 2**31 - 1), st.integers(0, 2**31 - 1)),
    st.builds(cs.SetInputVel, f32, f32),
    st.builds(cs.SetLimits, f32, f32),
    st.builds(cs.Iq, f32, f32),
    st.builds(cs.BusVoltageCurrent, f32, f32),
    st.builds(cs.Reboot),
    st.builds(cs.ClearErrors),
)


@pytest.fixture(scope="module")
def db():
    dbc = require_shared("fixtures", "odrive", "odrive-cansimple.dbc")
    cantools = pytest.importorskip("cantools", reason="cantools (dev extra) is the DBC oracle")
    return cantools.database.load_file(str(dbc))


def _ours(msg) -> dict[str, float | int]:
    return {
        sig: int(v) if isinstance(v, bool) else v for f, sig in MAPPING[type(msg)][1].items() for v in [getattr(msg, f)]
    }


@settings(max_examples=fuzz_examples(300), deadline=None)
@given(msg=messages, node_id=node)
def test_everything_we_encode_decodes_identically_in_the_dbc(db, msg, node_id):
    frame = cs.to_can(node_id, msg)
    dbc_msg = db.get_message_by_frame_id(frame.arbitration_id)
    assert dbc_msg.name == f"Axis{node_id}_{MAPPING[type(msg)][0]}"  # the id layout: node << 5 | cmd
    assert frame.dlc == dbc_msg.length
    decoded = db.decode_message(frame.arbitration_id, bytes(frame.data), decode_choices=False)
    assert decoded == _ours(msg)


@settings(max_examples=fuzz_examples(300), deadline=None)
@given(msg=messages, node_id=node)
def test_everything_cantools_encodes_we_decode_back(db, msg, node_id):
    name, _sigs = MAPPING[type(msg)]
    dbc_msg = db.get_message_by_name(f"Axis{node_id}_{name}")
    data = dbc_msg.encode(_ours(msg), strict=False)
    got_node, got = cs.parse_frame(dbc_msg.frame_id, data)
    assert got_node == node_id
    assert got == msg


def test_estop_is_not_in_the_dbc_but_has_cmd_2(db):
    assert db.get_message_by_name("Axis0_Heartbeat").frame_id == 0x001
    with pytest.raises(KeyError):
        db.get_message_by_frame_id(3 << 5 | 2)
    frame = cs.to_can(3, cs.Estop())
    assert (frame.arbitration_id, frame.dlc, bytes(frame.data)) == (0x62, 0, b"")
    assert cs.parse_message(frame) == (3, cs.Estop())


def test_arbitration_id_and_docs_example():
    assert cs.arbitration_id(0x01, 0x0C) == 0x2C  # the protocol document's own example
    assert cs.split_id(0x2C) == (1, 0x0C)
    assert cs.arbitration_id(63, 31) == 0x7FF
    with pytest.raises(ValueError):
        cs.arbitration_id(64, 1)
    assert cs.arbitration_id(0x123456, 7, extended=True) == 0x123456 << 5 | 7


def test_known_bytes_of_set_input_vel_and_heartbeat():
    frame = cs.to_can(1, cs.SetInputVel(10.0, 0.0))
    assert frame.arbitration_id == 0x2D
    assert bytes(frame.data) == struct.pack("<ff", 10.0, 0.0)
    hb = cs.Heartbeat(0x800, cs.AxisState.CLOSED_LOOP_CONTROL, True, False, True, True)
    assert hb.encode() == bytes([0, 8, 0, 0, 8, 1, 0, 0x81])


def test_motor_error_keeps_64_bits_of_the_firmware():
    big = cs.MotorError(0x8_0000_0001)  # UNKNOWN_GAINS | PHASE_RESISTANCE_OUT_OF_RANGE
    assert cs.parse_frame(cs.arbitration_id(0, 3), big.encode()) == (0, big)


def test_rtr_and_dlc0_requests():
    for cmd in (
        cs.Cmd.GET_IQ,
        cs.Cmd.GET_ENCODER_ESTIMATES,
        cs.Cmd.GET_BUS_VOLTAGE_CURRENT,
        cs.Cmd.GET_MOTOR_ERROR,
        cs.Cmd.GET_ENCODER_ERROR,
        cs.Cmd.GET_CONTROLLER_ERROR,
    ):
        rtr = cs.request(5, cmd)
        assert rtr.is_remote_frame and rtr.dlc == 8 and rtr.arbitration_id == 5 << 5 | cmd
        assert cs.parse_message(rtr) == (5, cs.Request(cmd))
        assert cs.parse_frame(5 << 5 | cmd, b"") == (5, cs.Request(cmd))  # fw >= 0.5.5: DLC 0 asks too
    with pytest.raises(ValueError):
        cs.request(0, cs.Cmd.SET_INPUT_VEL)
    with pytest.raises(cs.CanParseError):
        cs.parse_frame(cs.arbitration_id(0, cs.Cmd.SET_LIMITS), b"", is_remote=True)


def test_bad_frames_raise_the_one_parse_error():
    with pytest.raises(cs.CanParseError, match="needs 8"):
        cs.parse_frame(cs.arbitration_id(0, cs.Cmd.SET_LIMITS), b"\0" * 7)
    with pytest.raises(cs.CanParseError, match="not supported"):
        cs.parse_frame(cs.arbitration_id(0, cs.Cmd.SET_INPUT_POS), b"\0" * 8)
    with pytest.raises(cs.CanParseError):
        cs.parse_frame(0x800, b"")  # 12 bits is not a standard id
    with pytest.raises(cs.CanParseError):
        cs.parse_message(can.Message(is_error_frame=True))


def test_encode_refuses_nan_and_out_of_range():
    with pytest.raises(ValueError):
        cs.SetInputVel(math.nan).encode()
    with pytest.raises(ValueError):
        cs.SetLimits(math.inf, 10.0).encode()
    with pytest.raises(ValueError):
        cs.SetAxisState(-1).encode()


def test_error_names():
    assert cs.error_names(0) == "NONE"
    assert cs.error_names(0x4800) == "WATCHDOG_TIMER_EXPIRED|ESTOP_REQUESTED"
    assert cs.error_names(0x1 | 0x1000_0000) == "INVALID_STATE|0x10000000"


@settings(max_examples=fuzz_examples(1000), deadline=None)
@given(
    arb_id=st.one_of(st.integers(0, 0x7FF), st.integers(-(2**31), 2**32)),
    data=st.binary(min_size=0, max_size=12),
    is_remote=st.booleans(),
    is_extended=st.booleans(),
)
def test_fuzz_decoder_raises_only_can_parse_error(arb_id, data, is_remote, is_extended):
    try:
        node_id, msg = cs.parse_frame(arb_id, data, is_remote, is_extended)
    except cs.CanParseError:
        return
    assert 0 <= node_id <= cs.MAX_NODE_ID_EXTENDED
    if not isinstance(msg, cs.Request):  # decoding is deterministic (repr: NaN payloads compare equal)
        assert repr(type(msg).decode(data)) == repr(msg)


@settings(
    max_examples=fuzz_examples(2000), deadline=timedelta(seconds=5)
)  # a time bound per frame (generous: not a speed test)
@given(
    arb_id=st.integers(0, 0x1FFFFFFF),
    data=st.binary(max_size=8),
    remote=st.booleans(),
    extended=st.booleans(),
)
def test_fuzz_any_frame_decodes_or_raises_only_can_parse_error(arb_id, data, remote, extended):
    """The documented contract of parse_frame: a message, or CanParseError (a BeambenchError) — nothing else."""
    from beambench.common.errors import BeambenchError

    try:
        node, msg = cs.parse_frame(arb_id, data, remote, extended)
    except cs.CanParseError as exc:
        assert isinstance(exc, BeambenchError)
        return
    assert 0 <= node <= (0xFFFFFF if extended else 0x3F)
    assert isinstance(msg, (cs.Request, *cs.MESSAGES.values()))
