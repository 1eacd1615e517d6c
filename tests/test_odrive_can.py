"""OdriveCanMotor against the emulated ODrive over python-can's virtual bus (real frames, no mocks)."""

from __future__ import annotations

import contextlib
import math
import re
import time
import uuid
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from beambench.acquisition.batch import Batch
from beambench.acquisition.capabilities import DeviceFault, Motor, MotorLimits
from beambench.acquisition.streams import motor_spec
from beambench.devices.odrive import cansimple as cs
from beambench.devices.odrive.can_link import RECEIVE_COALESCE_S, receive_ns
from beambench.devices.odrive.can_motor import OdriveCanMotor
from beambench.devices.odrive.can_ping import ping
from beambench.devices.odrive.can_timing import CanMotorTiming
from beambench.devices.odrive.cansimple import AxisError, AxisState
from beambench.devices.odrive.limits import MAX_VEL_LIMIT, LimitError
from beambench.devices.receive_time import mono_minus_real_ns
from beambench.emulators.odrive_can import (
    EmulatedOdrive,
    OdriveAxisModel,
    OdriveEmulatorConfig,
)
from conftest import fuzz_examples, holds_for, raised, wait_until

NODE = 3
CAL_S = 0.25
LIMITS = MotorLimits(max_frequency_hz=10.0, max_current_a=5.0, amplitude_mm=2.0)


def read_rows(stream, n: int, done=None) -> Batch:  # type: ignore[no-untyped-def]
    """Read ``stream`` (as the runner does, every 20 ms) until it gave more than ``n`` rows and ``done`` holds
    for them; all of them."""
    batches: list[Batch] = []

    def enough() -> bool:
        batches.append(stream.read())
        return sum(map(len, batches)) > n and (done is None or done(Batch.concat(batches)))

    wait_until(enough, what=f"{n} rows", interval_s=0.02)
    return Batch.concat(batches)


def log_frames(path: Path) -> list[can.Message]:
    return list(can.LogReader(str(path)))


def sent_to_node(frames, cmd: cs.Cmd) -> list[tuple[int, object]]:
    """(index in the log, decoded message) of every data frame to NODE with this command."""
    out = []
    for i, f in enumerate(frames):
        if f.arbitration_id == cs.arbitration_id(NODE, cmd) and not f.is_remote_frame and f.dlc:
            out.append((i, cs.parse_frame(f.arbitration_id, f.data)[1]))
    return out


@pytest.fixture
def channel():
    return f"odrive-{uuid.uuid4().hex}"


def _emu_config() -> OdriveEmulatorConfig:
    return OdriveEmulatorConfig(node_id=NODE, calibration_s=CAL_S, watchdog_timeout_s=0.3, vel_ramp_rate=40.0)


@pytest.fixture
def emu(channel):
    with EmulatedOdrive(channel=channel, config=_emu_config()) as e:
        yield e
        assert e.error is None


@pytest.fixture
def motor(channel, emu, tmp_path):
    m = OdriveCanMotor(channel, "virtual", NODE, can_log=tmp_path / "traffic.asc")
    yield m
    m.close()


def test_satisfies_motor_protocol(motor):
    assert isinstance(motor, Motor)
    assert motor.describe() == motor_spec()


def test_arm_calibrates_then_enters_closed_loop(motor, emu):
    t0 = time.monotonic()
    motor.arm(LIMITS)
    elapsed = time.monotonic() - t0
    assert emu.snapshot()["state"] == AxisState.CLOSED_LOOP_CONTROL
    assert elapsed >= CAL_S  # it really waited for the calibration
    states = [s for _, s in emu.model.transitions]
    assert states == [
        AxisState.IDLE,
        AxisState.FULL_CALIBRATION_SEQUENCE,
        AxisState.IDLE,
        AxisState.CLOSED_LOOP_CONTROL,
    ]
    motor.check()
    assert motor.heartbeat.axis_state == AxisState.CLOSED_LOOP_CONTROL


def test_a_starved_emulator_still_shows_the_calibration_it_ran(motor, emu):
    """The emulator's thread gets no CPU for longer than the calibration right after it starts one (a loaded
    host): the heartbeats that fell due meanwhile go out late but say what the axis did at their time, so the
    driver sees the calibration and arms, instead of "did not start calibrating"."""
    emu.stall_after(cs.Cmd.SET_AXIS_STATE, 2 * CAL_S)
    motor.arm(LIMITS)
    assert emu.snapshot()["state"] == AxisState.CLOSED_LOOP_CONTROL
    assert emu.stalls == 1  # the stall really happened


def test_limits_and_mode_sent_before_calibration_and_closed_loop(motor, emu, tmp_path):
    motor.arm(LIMITS)
    motor.close()
    frames = log_frames(tmp_path / "traffic.asc")
    ((i_lim, lim),) = sent_to_node(frames, cs.Cmd.SET_LIMITS)
    ((i_mode, mode),) = sent_to_node(frames, cs.Cmd.SET_CONTROLLER_MODE)
    states = sent_to_node(frames, cs.Cmd.SET_AXIS_STATE)
    i_cal = next(i for i, m in states if m.state == AxisState.FULL_CALIBRATION_SEQUENCE)
    i_cl = next(i for i, m in states if m.state == AxisState.CLOSED_LOOP_CONTROL)
    assert i_lim < i_mode < i_cal < i_cl
    assert lim.vel_limit == pytest.approx(11.0)  # 10 Hz × 1.1 headroom: a real limit, never 8000
    assert lim.current_limit == pytest.approx(5.0)
    assert (mode.control_mode, mode.input_mode) == (cs.ControlMode.VELOCITY_CONTROL, cs.InputMode.VEL_RAMP)
    assert states[-1][1].state == AxisState.IDLE  # close() idled
    assert emu.snapshot()["vel_limit"] == pytest.approx(11.0)


def test_velocity_ramps_to_setpoint_and_telemetry_is_a_motor_batch(motor, emu):
    motor.start()
    motor.arm(LIMITS)
    motor.read()
    motor.set_frequency(8.0)
    wait_until(lambda: emu.snapshot()["vel_setpoint"] == 8.0, what="the ramp to reach 8 turn/s")
    # the PI loop overshoots a little after the ramp, then settles (~0.1 s time constant)
    batch = read_rows(motor, 20, lambda b: b.columns["velocity"][-1] == pytest.approx(8.0, rel=0.01))
    motor.check()
    spec = motor_spec()
    assert set(batch.columns) == set(spec.columns)
    for name, col in spec.columns.items():
        assert batch.columns[name].dtype == np.dtype(col.dtype)
    assert len(batch) > 20
    assert np.all(np.diff(batch.host_time_ns) >= 0) and np.all(np.diff(batch.device_time) >= 0)
    vel, t = batch.columns["velocity"], batch.device_time
    assert vel[-1] == pytest.approx(8.0, rel=0.01)
    assert vel.max() < 8.0 * 1.05
    assert batch.columns["velocity_setpoint"][-1] == 8.0
    assert np.all(batch.columns["axis_state"] == AxisState.CLOSED_LOOP_CONTROL)
    assert np.all(batch.columns["axis_error"] == 0)
    assert batch.columns["bus_voltage"][-1] == pytest.approx(24.0, abs=0.1)
    # the ramp: speed rises at most at vel_ramp_rate (40 turn/s²) plus a little loop overshoot
    # over 5 telemetry periods (~50 ms): a frame sent a few ms late by a busy emulator thread must not read as
    # a steep ramp between two neighbouring samples
    rising = vel < 7.5
    v_r, t_r = vel[rising], t[rising]
    slope = (v_r[5:] - v_r[:-5]) / (t_r[5:] - t_r[:-5])
    assert slope.max() < 40.0 * 1.5
    assert np.all(np.isfinite(batch.columns["iq_measured"][-5:]))
    assert np.all(batch.columns["position"][-1] > batch.columns["position"][0])


def test_receive_time_is_the_interfaces_wall_clock_stamp_moved_to_the_monotonic_clock():
    now, offset = 5_000_000_000_000, -1_700_000_000_000_000_000
    wall = (now - offset - 3_000_000) * 1e-9  # arrived 3 ms ago on the wall clock
    assert receive_ns(can.Message(timestamp=wall), now, offset) == pytest.approx(now - 3_000_000, abs=1_000)
    assert receive_ns(can.Message(timestamp=0.0), now, offset) == now  # no stamp: the handling time
    assert receive_ns(can.Message(timestamp=wall + 0.01), now, offset) == now  # in the future: another clock
    assert receive_ns(can.Message(timestamp=wall - 2.0), now, offset) == now  # 2 s old: another clock
    assert receive_ns(can.Message(timestamp=12.5), now, offset) == now  # e.g. an adapter's uptime clock


def test_telemetry_is_stamped_at_arrival_not_when_the_receive_thread_handles_it(channel, emu, tmp_path):
    """The receive thread handles frames in gatherings every ~RECEIVE_COALESCE_S; the rows' host times must
    still be the frames' arrival times: 100 Hz Encoder_Estimates spaced ~10 ms apart, not bunched (handling
    times would put several rows within a fraction of a millisecond, then a 20 ms gap)."""
    with OdriveCanMotor(channel, "virtual", NODE) as m:
        before = mono_minus_real_ns()
        m.start()
        batch = read_rows(m, 50)
        after = mono_minus_real_ns()
    assert len(batch) > 50
    gaps_ms = np.diff(batch.host_time_ns) * 1e-6
    assert RECEIVE_COALESCE_S * 1e3 > 15  # the premise: gatherings longer than the 10 ms telemetry period
    # arrival times keep the sender's ~10 ms spacing (handling times would put the median gap near 0); a sender
    # starved on a loaded host sends late and spaces them wider, never closer
    assert 8.0 <= np.median(gaps_ms) <= 30.0, np.round(gaps_ms, 2)
    assert np.mean(gaps_ms < 2.0) < 0.2, np.round(gaps_ms, 2)
    # host and device clocks agree: both are the frame's stamp, the host's moved from the wall clock onto the
    # monotonic one, so they differ by that offset only. (Not "they move together": this VM's wall clock was seen
    # slewed by 5 ms in that second against the monotonic clock, and the offset moves with it.)
    offset_ns = batch.host_time_ns - np.round(batch.device_time * 1e9).astype(np.int64)
    lo, hi = min(before, after) - 1_000_000, max(before, after) + 1_000_000
    assert np.all((offset_ns >= lo) & (offset_ns <= hi)), (before, after, offset_ns - before)


def test_frequency_above_limit_is_refused_before_anything_is_sent(motor, emu, tmp_path):
    with pytest.raises(DeviceFault, match="before arm"):
        motor.set_frequency(1.0)
    motor.arm(LIMITS)
    for bad in (10.5, -11.0, math.nan, math.inf):
        with pytest.raises(LimitError):
            motor.set_frequency(bad)
    motor.set_frequency(10.0)  # at the limit is allowed
    motor.close()
    vels = [m.vel for _, m in sent_to_node(log_frames(tmp_path / "traffic.asc"), cs.Cmd.SET_INPUT_VEL)]
    assert max(abs(v) for v in vels) == 10.0
    assert emu.snapshot()["input_vel"] == 0.0  # and the idle on close zeroed it


def test_unsafe_limits_are_refused_before_anything_is_sent(channel, emu, tmp_path):
    with OdriveCanMotor(channel, "virtual", NODE, can_log=tmp_path / "t.asc") as m:
        with pytest.raises(LimitError):
            m.arm(MotorLimits(8000.0, 5.0, 2.0))  # the old script's vel_limit
        with pytest.raises(LimitError):
            m.arm(MotorLimits(MAX_VEL_LIMIT, 5.0, 2.0))
        with pytest.raises(LimitError):
            m.arm(MotorLimits(10.0, 0.0, 2.0))
    frames = log_frames(tmp_path / "t.asc")
    assert sent_to_node(frames, cs.Cmd.SET_LIMITS) == []
    assert emu.snapshot()["vel_limit"] == 2.0  # untouched firmware default


def test_watchdog_expires_when_feeding_stops(motor, emu):
    motor.arm(LIMITS)
    motor.set_frequency(3.0)
    # longer than the 0.3 s watchdog: the feeder keeps it alive
    holds_for(lambda: raised(motor.check, DeviceFault) is None, 0.4, "no fault while fed")
    assert emu.snapshot()["state"] == AxisState.CLOSED_LOOP_CONTROL
    motor.stop_feeding()
    wait_until(lambda: emu.snapshot()["state"] == AxisState.IDLE, what="watchdog idle")
    snap = emu.snapshot()
    assert snap["axis_error"] == AxisError.WATCHDOG_TIMER_EXPIRED
    t_idle = emu.model.transitions[-1][0]
    assert t_idle - emu.model.last_feed >= 0.3  # it expired only after 0.3 s without a frame
    assert "WATCHDOG_TIMER_EXPIRED" in str(wait_until(lambda: raised(motor.check, DeviceFault), 2.0))


def test_heartbeat_lost_raises_device_fault(motor, emu):
    motor.arm(LIMITS)
    motor.check()
    emu.stop()
    t_stop = time.monotonic()
    err = wait_until(lambda: raised(motor.check, DeviceFault), 3.0, "the heartbeat loss")
    assert time.monotonic() - t_stop > 1.0 - 0.1  # the last heartbeat may predate the stop by one period
    assert "heartbeat lost" in str(err) and "> 1000 ms" in str(err)  # the default: ten 100 ms periods


def test_estop(motor, emu):
    motor.arm(LIMITS)
    motor.set_frequency(4.0)
    motor.estop()
    wait_until(lambda: emu.snapshot()["state"] == AxisState.IDLE, what="estop idle")
    assert emu.snapshot()["axis_error"] == AxisError.ESTOP_REQUESTED
    assert "ESTOP_REQUESTED" in str(wait_until(lambda: raised(motor.check, DeviceFault), 2.0))
    with pytest.raises(DeviceFault):
        motor.set_frequency(1.0)  # disarmed
    motor.arm(LIMITS)  # arm clears errors and recovers
    assert emu.snapshot()["state"] == AxisState.CLOSED_LOOP_CONTROL
    motor.check()


def test_injected_motor_error_is_named(motor, emu):
    motor.arm(LIMITS)
    emu.inject_error(motor=0x1000)  # CURRENT_LIMIT_VIOLATION

    def named() -> DeviceFault | None:  # the RTR answer for the motor error has arrived
        fault = raised(motor.check, DeviceFault)
        return fault if fault is not None and "0x1000" in str(fault) else None

    assert re.search(r"MOTOR_FAILED.*motor error 0x1000", str(wait_until(named, 3.0, "the motor error")))


def test_idle_on_exit_from_context_manager_after_exception(channel, emu):
    with pytest.raises(RuntimeError, match="boom"), OdriveCanMotor(channel, "virtual", NODE) as m:
        m.arm(LIMITS)
        m.set_frequency(5.0)
        raise RuntimeError("boom")
    wait_until(lambda: emu.snapshot()["state"] == AxisState.IDLE, what="idle after exception")
    assert emu.snapshot()["axis_error"] == 0  # a commanded idle, not a watchdog trip
    assert emu.snapshot()["input_vel"] == 0.0


def test_close_after_fault_idles_and_is_idempotent(motor, emu, tmp_path):
    motor.arm(LIMITS)
    emu.inject_error(encoder=0x4)
    wait_until(lambda: raised(motor.check, DeviceFault), 2.0, "the encoder fault")
    motor.idle()
    motor.idle()
    motor.close()
    motor.close()
    motor.idle()  # after close: a no-op, never raises
    states = [m.state for _, m in sent_to_node(log_frames(tmp_path / "traffic.asc"), cs.Cmd.SET_AXIS_STATE)]
    assert states[-3:] == [AxisState.IDLE] * 3
    assert emu.snapshot()["state"] == AxisState.IDLE


@pytest.fixture
def numbered_channel(channel):
    """A bus name ending in digits beyond .blf's 16-bit channel field (python-can reads the number off it)."""
    return channel + "-9876543"


@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_can_log_has_the_traffic(numbered_channel, tmp_path, suffix):
    channel = numbered_channel
    path = tmp_path / f"run{suffix}"
    t_start = time.time()
    with (
        EmulatedOdrive(channel=channel, config=_emu_config()),
        OdriveCanMotor(channel, "virtual", NODE, can_log=path) as m,
    ):
        m.arm(LIMITS)
        m.set_frequency(2.0)
        m.start()
        read_rows(m, 10)  # telemetry flows while the log records
    t_end = time.time()
    frames = log_frames(path)
    parsed = [cs.parse_message(f) for f in frames]  # every logged frame is valid CAN Simple
    kinds = {type(msg) for _, msg in parsed}
    assert {
        cs.Heartbeat,
        cs.EncoderEstimates,
        cs.SetLimits,
        cs.SetInputVel,
        cs.SetAxisState,
        cs.Iq,
        cs.BusVoltageCurrent,
        cs.Request,
    } <= kinds
    rx = [f for f in frames if f.is_rx]
    tx = [f for f in frames if not f.is_rx]
    assert rx and tx
    assert all(
        cs.split_id(f.arbitration_id)[1]
        in (cs.Cmd.HEARTBEAT, cs.Cmd.GET_ENCODER_ESTIMATES, cs.Cmd.GET_IQ, cs.Cmd.GET_BUS_VOLTAGE_CURRENT)
        for f in rx
    )
    assert any(f.is_remote_frame for f in tx)
    # timestamps span this run (rx: the sender's wall time on the virtual bus; tx: ours at send;
    # .asc stores them relative to the first frame, .blf absolute)
    ts = np.array([f.timestamp for f in frames])
    assert 0.3 < ts.max() - ts.min() <= t_end - t_start + 0.01
    assert any(isinstance(msg, cs.SetInputVel) and msg.vel == 2.0 for _, msg in parsed)


def test_ping(channel, emu):
    info = ping(channel, "virtual", listen_s=1.0)
    assert info["found"] and info["nodes"] == [NODE] and info["node_id"] == NODE
    assert info["axis_state"] == "IDLE" and info["axis_error"] == "NONE"
    assert info["bus_voltage_v"] == pytest.approx(24.0)
    assert info["heartbeat_hz"] == pytest.approx(10, rel=0.3)
    silent = ping(f"nothing-{uuid.uuid4().hex}", "virtual", node_id=1, listen_s=0.15)
    assert silent["found"] is False and silent["nodes"] == []


def test_arm_without_odrive_raises(tmp_path):
    with OdriveCanMotor(
        f"empty-{uuid.uuid4().hex}", "virtual", NODE, timing=CanMotorTiming(heartbeat_timeout_s=0.1)
    ) as m:
        with pytest.raises(DeviceFault, match="no heartbeat"):
            m.arm(LIMITS)
        with pytest.raises(DeviceFault, match="no heartbeat"):
            m.check()


@settings(max_examples=fuzz_examples(500), deadline=None)
@given(arb_id=st.integers(0, 0x7FF), data=st.binary(max_size=8), rtr=st.booleans())
def test_fuzz_frames_never_crash_driver_or_emulator(arb_id, data, rtr):
    frame = can.Message(arbitration_id=arb_id, data=data, is_remote_frame=rtr, dlc=8 if rtr else len(data))
    driver = OdriveCanMotor("unused", "virtual", NODE)  # never opened: only its receive path runs
    driver.receive(frame)
    with contextlib.suppress(DeviceFault):
        driver.check()  # a fuzzed heartbeat may carry error bits: then a DeviceFault, nothing else
    model = OdriveAxisModel(OdriveEmulatorConfig(node_id=NODE, calibrated=True, watchdog_timeout_s=0))
    model.handle(cs.SetControllerMode(cs.ControlMode.VELOCITY_CONTROL, cs.InputMode.VEL_RAMP))
    model.handle(cs.SetAxisState(AxisState.CLOSED_LOOP_CONTROL))
    try:
        _, msg = cs.parse_message(frame)
    except cs.CanParseError:
        return
    for reply in model.handle(msg):
        reply.encode()
    model.advance(0.5)
    for reply in (model.heartbeat(), model.estimates(), *model.handle(cs.Request(cs.Cmd.GET_IQ))):
        cs.to_can(0, reply)  # everything the emulator would send stays encodable (finite)


def test_axis_idled_by_someone_else_is_a_fault(channel, motor, emu):
    motor.arm(LIMITS)
    with can.Bus(interface="virtual", channel=channel) as other_host:
        other_host.send(cs.to_can(NODE, cs.SetAxisState(AxisState.IDLE)))
    assert "left closed loop" in str(wait_until(lambda: raised(motor.check, DeviceFault), 2.0))


def test_bad_log_suffix_is_refused_up_front(tmp_path):
    with pytest.raises(ValueError, match="unknown log format"):
        OdriveCanMotor("x", "virtual", NODE, can_log=tmp_path / "traffic.pcap")


@pytest.mark.parametrize(("kind", "code"), [("motor", 0x1), ("encoder", 0x4)])
def test_the_first_fault_report_reads_the_error_register_first(motor, emu, kind, code):
    """The heartbeat only flags MOTOR_FAILED; the report must carry the register's value, read
    on the spot (was ``motor error 0x0``: the value before the RTR answer arrived)."""
    motor.arm(LIMITS)
    emu.inject_error(**{kind: code})
    first = str(wait_until(lambda: raised(motor.check, DeviceFault), 3.0, "a fault", interval_s=0.001))
    assert f"{kind} error {code:#x}" in first, first


def test_a_heartbeat_waited_for_is_found_behind_the_burst_that_followed_it():
    """A stalled host reads a full socket buffer at once: the closed-loop heartbeat a waiter looks for came before
    heartbeats that say otherwise, and the wait still finds it (the driver keeps a log, not only the latest);
    a heartbeat from before the wait began, or from another node, is not an answer."""
    driver = OdriveCanMotor("unused", "virtual", NODE)  # never opened: only its receive path runs
    t0 = time.monotonic_ns()
    driver.receive(cs.to_can(NODE, cs.Heartbeat(axis_state=AxisState.CLOSED_LOOP_CONTROL)), t0 - 5)  # before
    driver.receive(cs.to_can(NODE + 1, cs.Heartbeat(axis_state=AxisState.CLOSED_LOOP_CONTROL)), t0 + 1)
    burst = [AxisState.IDLE, AxisState.CLOSED_LOOP_CONTROL, AxisState.IDLE, AxisState.IDLE]
    for i, state in enumerate(burst):
        driver.receive(cs.to_can(NODE, cs.Heartbeat(axis_state=state, axis_error=i)), t0 + 10 + i)
    assert driver.heartbeat == cs.Heartbeat(axis_state=AxisState.IDLE, axis_error=3)  # the latest is idle
    hb = driver.view.wait_heartbeat(lambda h: h.axis_state == AxisState.CLOSED_LOOP_CONTROL, 0.0, t0)
    assert hb == cs.Heartbeat(axis_state=AxisState.CLOSED_LOOP_CONTROL, axis_error=1)
    assert driver.view.wait_heartbeat(lambda h: h.axis_error == 7, 0.01, t0) is None  # none such: a timeout
    assert driver.health()["frames_received"] == 5  # the other node's frame is not this axis's
