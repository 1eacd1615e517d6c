"""The emulated ODrive axis: state machine and mechanics with explicit time, then its cyclic traffic on a bus."""

from __future__ import annotations

import math
import uuid

import can
import numpy as np
import pytest

from beambench.devices.odrive import cansimple as cs
from beambench.devices.odrive.cansimple import (
    AxisError,
    AxisState,
    ControlMode,
    InputMode,
)
from beambench.emulators.odrive_can import (
    EmulatedOdrive,
    OdriveAxisModel,
    OdriveEmulatorConfig,
)

S = AxisState


def closed_loop_model(**cfg) -> OdriveAxisModel:
    m = OdriveAxisModel(OdriveEmulatorConfig(calibrated=True, watchdog_timeout_s=0, **cfg), t=0.0)
    m.handle(cs.SetControllerMode(ControlMode.VELOCITY_CONTROL, InputMode.VEL_RAMP))
    m.handle(cs.SetLimits(50.0, 10.0))
    m.handle(cs.SetAxisState(S.CLOSED_LOOP_CONTROL))
    assert m.state == S.CLOSED_LOOP_CONTROL
    return m


def run(m: OdriveAxisModel, until: float, dt: float = 0.005) -> list[tuple[float, float, float, float]]:
    """(t, vel_setpoint, velocity, iq) every ``dt`` up to ``until``."""
    out = []
    while m.t < until - 1e-12:
        m.advance(min(m.t + dt, until))
        out.append((m.t, m.vel_setpoint, m.velocity, m.iq_measured))
    return out


def test_boot_closed_loop_needs_calibration_then_velocity_mode():
    m = OdriveAxisModel(OdriveEmulatorConfig(calibration_s=0.5), t=0.0)
    assert m.control_mode == ControlMode.POSITION_CONTROL  # firmware boot default
    m.handle(cs.SetAxisState(S.CLOSED_LOOP_CONTROL))
    assert (m.state, m.axis_error) == (S.IDLE, AxisError.INVALID_STATE)
    m.handle(cs.SetAxisState(S.FULL_CALIBRATION_SEQUENCE))
    assert m.state == S.IDLE, "latched error: requests are ignored until Clear_Errors"
    m.handle(cs.ClearErrors())
    m.handle(cs.SetAxisState(S.FULL_CALIBRATION_SEQUENCE))
    m.advance(0.49)
    assert m.state == S.FULL_CALIBRATION_SEQUENCE
    m.advance(0.51)
    assert m.state == S.IDLE and m.motor_calibrated and m.encoder_ready
    assert [s for _, s in m.transitions] == [S.IDLE, S.FULL_CALIBRATION_SEQUENCE, S.IDLE]
    assert m.transitions[2][0] == pytest.approx(0.5)
    m.handle(cs.SetAxisState(S.CLOSED_LOOP_CONTROL))  # still in position control
    assert m.state == S.IDLE and m.axis_error == AxisError.CONTROLLER_FAILED
    assert m.controller_error == cs.ControllerError.INVALID_INPUT_MODE
    m.handle(cs.ClearErrors())
    m.handle(cs.SetControllerMode(ControlMode.VELOCITY_CONTROL, InputMode.VEL_RAMP))
    m.handle(cs.SetAxisState(S.CLOSED_LOOP_CONTROL))
    assert m.state == S.CLOSED_LOOP_CONTROL and m.axis_error == 0


def test_velocity_ramp_rate_and_tracking():
    m = closed_loop_model(vel_ramp_rate=40.0)
    m.handle(cs.SetInputVel(10.0, 0.0))
    trace = np.array(run(m, 1.0))
    t, sp, vel = trace[:, 0], trace[:, 1], trace[:, 2]
    ramp = (t > 0.02) & (t < 0.23)
    slope = np.polyfit(t[ramp], sp[ramp], 1)[0]
    assert slope == pytest.approx(40.0, rel=1e-3)  # the setpoint ramps at vel_ramp_rate
    assert sp[-1] == pytest.approx(10.0)
    assert vel[-1] == pytest.approx(10.0, rel=0.01)  # the PI loop tracks the setpoint
    rising = t < 0.25
    assert np.all(np.diff(vel[rising]) > 0), "velocity rises monotonically while the setpoint ramps"
    assert vel.max() < 10.0 * 1.05


def test_vel_limit_clamps_setpoint():
    m = closed_loop_model(vel_ramp_rate=200.0)
    m.handle(cs.SetLimits(5.0, 10.0))
    m.handle(cs.SetInputVel(20.0, 0.0))
    trace = np.array(run(m, 1.0))
    assert trace[:, 1].max() == pytest.approx(5.0)
    assert trace[-1, 2] == pytest.approx(5.0, rel=0.01)
    assert m.axis_error == 0


def test_current_limit_caps_iq_and_acceleration():
    cfg = OdriveEmulatorConfig()
    m = closed_loop_model(vel_ramp_rate=1e4)
    m.handle(cs.SetLimits(50.0, 0.5))
    m.handle(cs.SetInputVel(30.0, 0.0))
    trace = np.array(run(m, 0.3, dt=0.001))
    assert np.abs(trace[:, 3]).max() == pytest.approx(0.5)
    accel = np.diff(trace[:, 2]) / np.diff(trace[:, 0])
    # Newton at the current limit, from rest: (kt·I − Coulomb friction) / J, in turn/s²
    max_accel = (cfg.torque_constant * 0.5 - cfg.coulomb_friction) / (cfg.inertia * 2 * math.pi)
    assert accel.max() <= max_accel * 1.001
    assert accel[0] == pytest.approx(max_accel, rel=0.01)  # and it is reached: the step saturates the current


def test_overspeed_trips_controller():
    m = closed_loop_model(vel_ramp_rate=200.0)
    m.handle(cs.SetInputVel(10.0, 0.0))
    run(m, 0.5)
    m.handle(cs.SetLimits(2.0, 10.0))  # now 10 turn/s > 2 × 1.2
    m.advance(0.51)
    assert m.state == S.IDLE
    assert m.axis_error & AxisError.CONTROLLER_FAILED
    assert m.controller_error & cs.ControllerError.OVERSPEED


def test_watchdog_expires_only_without_frames():
    m = OdriveAxisModel(OdriveEmulatorConfig(calibrated=True, watchdog_timeout_s=0.2), t=0.0)
    m.handle(cs.SetControllerMode(ControlMode.VELOCITY_CONTROL, InputMode.VEL_RAMP))
    m.handle(cs.SetAxisState(S.CLOSED_LOOP_CONTROL))
    for k in range(1, 20):  # fed every 0.1 s for ~2 s: fine
        m.advance(0.1 * k)
        m.handle(cs.Request(cs.Cmd.GET_IQ))  # any frame feeds it, RTRs too
    assert m.state == S.CLOSED_LOOP_CONTROL
    m.advance(m.t + 0.19)
    assert m.state == S.CLOSED_LOOP_CONTROL
    m.advance(m.t + 0.02)
    assert m.state == S.IDLE and m.axis_error == AxisError.WATCHDOG_TIMER_EXPIRED


def test_estop_idles_and_latches_until_clear():
    m = closed_loop_model()
    m.handle(cs.SetInputVel(5.0, 0.0))
    run(m, 0.5)
    m.handle(cs.Estop())
    assert m.state == S.IDLE and m.axis_error == AxisError.ESTOP_REQUESTED
    m.handle(cs.SetAxisState(S.CLOSED_LOOP_CONTROL))
    assert m.state == S.IDLE
    hb = m.heartbeat()
    assert hb.axis_error == AxisError.ESTOP_REQUESTED and hb.axis_state == S.IDLE
    m.handle(cs.ClearErrors())
    m.handle(cs.SetAxisState(S.CLOSED_LOOP_CONTROL))
    assert m.state == S.CLOSED_LOOP_CONTROL


def test_idle_coasts_to_rest_without_reversing():
    m = closed_loop_model(vel_ramp_rate=200.0)
    m.handle(cs.SetInputVel(10.0, 0.0))
    run(m, 0.5)
    m.handle(cs.SetAxisState(S.IDLE))
    trace = np.array(run(m, 30.0, dt=0.05))
    vel = trace[:, 2]
    assert np.all(np.diff(vel) <= 1e-12) and vel.min() >= 0.0
    assert vel[-1] == 0.0
    assert np.all(trace[:, 3] == 0.0)  # no current in idle


def test_injected_errors_set_flags_and_answers():
    m = closed_loop_model()
    m.inject_error(motor=0x1000)
    assert m.state == S.IDLE and m.axis_error == AxisError.MOTOR_FAILED
    assert m.heartbeat().motor_error_flag and not m.heartbeat().encoder_error_flag
    assert m.handle(cs.Request(cs.Cmd.GET_MOTOR_ERROR)) == [cs.MotorError(0x1000)]
    m.handle(cs.ClearErrors())
    assert m.handle(cs.Request(cs.Cmd.GET_MOTOR_ERROR)) == [cs.MotorError(0)]


def test_reboot_restores_boot_config_and_node_id():
    m = closed_loop_model(node_id=2)
    m.handle(cs.SetAxisNodeId(9))
    assert m.node_id == 9
    m.handle(cs.SetLimits(7.0, 3.0))
    m.handle(cs.Reboot())
    assert (m.node_id, m.state, m.vel_limit, m.control_mode) == (2, S.IDLE, 2.0, ControlMode.POSITION_CONTROL)
    assert m.silent_until == pytest.approx(m.t + m.cfg.reboot_s)


def test_cyclic_messages_and_rtr_on_a_virtual_bus():
    channel = f"emu-{uuid.uuid4().hex}"
    with (
        EmulatedOdrive(channel=channel, config=OdriveEmulatorConfig(node_id=4)) as emu,
        can.Bus(interface="virtual", channel=channel) as sniffer,
    ):
        frames = []
        end = None
        while end is None or frames[-1].timestamp < end:
            f = sniffer.recv(timeout=1.0)
            assert f is not None, "emulator went silent"
            end = end or f.timestamp + 1.0
            frames.append(f)
        sniffer.send(cs.request(4, cs.Cmd.GET_BUS_VOLTAGE_CURRENT))
        answer = None
        while answer is None:
            f = sniffer.recv(timeout=1.0)
            assert f is not None
            _node, msg = cs.parse_message(f)
            if isinstance(msg, cs.BusVoltageCurrent):
                answer = msg
        assert answer.voltage == pytest.approx(24.0)
        assert emu.error is None
    parsed = [(f.timestamp, *cs.parse_message(f)) for f in frames]
    assert {node for _, node, _ in parsed} == {4}
    hb_t = [t for t, _, m in parsed if isinstance(m, cs.Heartbeat)]
    enc_t = [t for t, _, m in parsed if isinstance(m, cs.EncoderEstimates)]
    # cyclic rates of the firmware defaults, as messages per second over the second recorded: a starved emulator
    # sends what fell due late rather than skipping it, so the rates hold on a busy machine
    assert (len(hb_t) - 1) / (hb_t[-1] - hb_t[0]) == pytest.approx(10.0, rel=0.15)
    assert (len(enc_t) - 1) / (enc_t[-1] - enc_t[0]) == pytest.approx(100.0, rel=0.1)
