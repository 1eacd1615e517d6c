"""ODrive v3.6 (firmware 0.5.x) over CAN Simple with python-can, behind :class:`beambench.acquisition.capabilities.Motor`.

The crank turns once per stage cycle, so a step at frequency f Hz is a velocity of f turn/s.

Safety, in the order :meth:`OdriveCanMotor.arm` does it:

1. the limits are checked on the host first: ``vel_limit = max_frequency_hz × 1.1`` (a little headroom so
   the velocity loop's ripple does not hit the limit) and ``current_lim = max_current_a``; a velocity limit
   above :data:`MAX_VEL_LIMIT` is refused (the lab's old script set 8000 turn/s, which disables the limit);
2. Clear_Errors, then Set_Limits — before any motion or calibration;
3. Set_Controller_Mode(velocity control, VEL_RAMP) and an input velocity of 0;
4. the watchdog feeder starts: Set_Input_Vel with the current setpoint every ``feed_period_s`` (every frame
   to the axis feeds the firmware watchdog). CAN Simple 0.5.x has no message to *enable* the watchdog:
   ``axis.config.enable_watchdog`` and ``watchdog_timeout`` must be set once over USB and saved
   (:class:`beambench.devices.odrive.usb_motor.OdriveUsbMotor` does this when armed);
5. FULL_CALIBRATION_SEQUENCE if ``calibrate`` (incremental encoders need it after every power-up), waited for
   through the heartbeat; then CLOSED_LOOP_CONTROL, waited for (timeout → idle + :class:`DeviceFault`).

:meth:`~OdriveCanMotor.set_frequency` refuses anything above ``max_frequency_hz`` before a frame is sent.
:meth:`~OdriveCanMotor.idle` is idempotent and never raises; ``close()``/the context manager always idle.
:meth:`~OdriveCanMotor.check` raises :class:`DeviceFault` on axis error bits (named), on leaving closed loop
while armed, or when no heartbeat came for more than ``heartbeat_timeout_s`` (1 s: ten periods). The feeder stops
feeding when the heartbeat is lost, so a half-broken link lets the ODrive's own watchdog idle the motor.

Telemetry (:func:`beambench.acquisition.streams.motor_spec`): one row per Encoder_Estimates frame (100 Hz), with the
latest Iq and bus voltage (polled by RTR every ``poll_period_s``), the heartbeat's state and error, and the
commanded velocity. CAN Simple frames carry no device timestamp: ``device_time`` is python-can's message
timestamp (the interface's receive time — the kernel's for socketcan, the host's for the loopback bus, the sender's for the
virtual bus; host receive time if the interface gives none) and ``host_time_ns`` is that same time on the
monotonic clock when it is a recent wall-clock time (:func:`receive_ns`), else ``time.monotonic_ns()`` when the
driver handled the frame.

Receiving: one thread of the driver's own (not ``can.Notifier``) waits for a frame, then lets frames gather
for :data:`RECEIVE_COALESCE_S` and handles all that wait, so ~200 frames/s cost ~50 wake-ups instead of 200 (the
stamps above are the interface's receive times, so the wait costs no timing accuracy; a fault read from a
heartbeat is seen at most this much later, far inside the heartbeat and poll periods).

``can_log``: every frame sent and received is recorded with python-can's own ``can.Logger`` (.asc or .blf;
other python-can formats work too), fed by the receive thread and the senders.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import can

from beambench.acquisition.capabilities import DeviceFault, MotorLimits, PacksAhead, RefusesForeign
from beambench.acquisition.streams import MOTOR
from beambench.common.oserrors import can_open_problem
from beambench.devices.odrive import cansimple as cs
from beambench.devices.odrive.can_log import TrafficLog
from beambench.devices.odrive.can_log_formats import LOG_SUFFIXES
from beambench.devices.odrive.can_timing import (
    MAX_FRAMES_PER_WAKE,
    RECEIVE_COALESCE_S,
    CanMotorTiming,
    receive_ns,
)
from beambench.devices.odrive.cansimple import AxisState, ControlMode, InputMode
from beambench.devices.odrive.host_stall import HostStall, idle_not_confirmed
from beambench.devices.odrive.telemetry import (
    MAX_BUFFERED_ROWS,
    LimitError,
    TelemetryStream,
    current_limit_for,
    vel_limit_for,
)
from beambench.devices.receive_time import mono_minus_real_ns

DEFAULT_TIMING = CanMotorTiming()
IDLE_SEND_TRIES = 5  # each idle frame is sent up to this many times (a full TX queue, no memory for a moment)
IDLE_RETRY_S = 0.02

_ERROR_REGISTERS = (cs.Cmd.GET_MOTOR_ERROR, cs.Cmd.GET_ENCODER_ERROR, cs.Cmd.GET_CONTROLLER_ERROR)

HEARTBEAT_LOG = 64  # heartbeats kept for waiters: 6 s at the default 100 ms


class OdriveCanMotor(TelemetryStream):
    """One ODrive axis on a CAN bus (CAN Simple, firmware 0.5.x), satisfying the ``Motor`` protocol.

    ``interface``/``channel``/``bitrate`` are passed to ``can.Bus`` (``socketcan``/``can0`` on the rig,
    ``virtual`` in tests); or pass an open ``bus`` (then it is not shut down by :meth:`close`). ``timing``: how it
    arms and watches the axis (:class:`CanMotorTiming`).
    """

    name = MOTOR

    def __init__(
        self,
        channel: str = "can0",
        interface: str = "socketcan",
        node_id: int = 0,
        *,
        bitrate: int | None = None,
        bus: can.BusABC | None = None,
        own_bus: bool | None = None,
        can_log: str | Path | None = None,
        timing: CanMotorTiming = DEFAULT_TIMING,
        extended_id: bool = False,
    ) -> None:
        cs.arbitration_id(node_id, 0, extended_id)  # validates the node id
        self.channel, self.interface, self.node_id, self.bitrate = channel, interface, node_id, bitrate
        self.extended_id = extended_id
        self.can_log = Path(can_log) if can_log is not None else None
        if self.can_log is not None and self.can_log.suffix.lower() not in LOG_SUFFIXES:
            raise ValueError(f"can_log {self.can_log}: unknown log format (use one of {', '.join(LOG_SUFFIXES)})")
        self.timing = timing
        self.calibrate = timing.calibrate
        self.calibration_timeout_s = timing.calibration_timeout_s
        self.closed_loop_timeout_s = timing.closed_loop_timeout_s
        self.heartbeat_timeout_s = timing.heartbeat_timeout_s
        self.feed_period_s = timing.feed_period_s
        self.poll_period_s = timing.poll_period_s
        self.telemetry_timeout_s = timing.telemetry_timeout_s
        self._bus = bus
        self._own_bus = bus is None if own_bus is None else own_bus
        self._receiver: threading.Thread | None = None
        self._receiver_stop = threading.Event()
        self._log: TrafficLog | None = None
        self._tx_lock = threading.Lock()
        self._cond = threading.Condition()  # guards everything below
        self._guard = self._cond
        self._opened_ns: int | None = None
        self._hb: cs.Heartbeat | None = None
        self._hb_ns: int | None = None
        self._hb_count = 0
        # the latest heartbeats, (count, receive ns, heartbeat): a burst (a stalled host reading a full socket
        # buffer) must not hide the one a waiter looks for behind the ones after it
        self._hb_log: deque[tuple[int, int, cs.Heartbeat]] = deque(maxlen=HEARTBEAT_LOG)
        self._pos = math.nan
        self._vel = math.nan
        self._iq = math.nan
        self._vbus = math.nan
        self._ibus = math.nan
        self.motor_error = 0
        self.encoder_error = 0
        self.controller_error = 0
        self.error_read_timeout_s = 0.25  # how long a fault report waits for the error registers' answers
        self._error_replies = dict.fromkeys(_ERROR_REGISTERS, 0)  # answers received, per register
        self._setpoint = 0.0
        self._limits: MotorLimits | None = None
        self.vel_limit: float | None = None
        self.current_limit: float | None = None
        self._armed = False
        self._streaming = False
        self._rows: deque[tuple] = deque(maxlen=MAX_BUFFERED_ROWS)
        self._fault: str | None = None
        self.rx_count = 0
        self.rows_received = self.rows_evicted = 0  # TelemetryStream._buffer counts them
        self._telemetry_ns: int | None = None  # host time of the newest Encoder_Estimates
        self._streaming_ns: int | None = None  # when the telemetry stream started
        self.tx_count = 0
        self.parse_errors = 0
        self.send_errors: deque[str] = deque(maxlen=100)
        self.rx_errors: deque[str] = deque(maxlen=100)
        self._feeder: threading.Thread | None = None
        self._feeder_stop = threading.Event()
        self._tx_paused = False
        self._closed = False
        self._stall = HostStall()  # the host's own stall (no CPU time), not the ODrive's silence
        # the idle frames, built now: sending them must not need memory the run may have run out of
        self._idle_sent_ns: int | None = None
        self._idle_frames = tuple(
            cs.to_can(node_id, m, extended_id) for m in (cs.SetAxisState(AxisState.IDLE), cs.SetInputVel(0.0, 0.0))
        )

    # ------------------------------------------------------------------ bus lifecycle
    def open(self) -> None:
        """Open the bus, start receiving (and logging). Idempotent."""
        if self._receiver is not None:
            return
        if self._closed:
            raise DeviceFault("OdriveCanMotor is closed")
        if self._bus is None:
            kwargs: dict[str, Any] = {"interface": self.interface, "channel": self.channel}
            if self.bitrate is not None:
                kwargs["bitrate"] = self.bitrate
            try:
                self._bus = can.Bus(**kwargs)
            except (can.CanError, OSError, ValueError, ImportError) as exc:
                why = can_open_problem(self.interface, self.channel, exc, self.bitrate)
                raise DeviceFault(f"cannot open CAN bus {self.interface}:{self.channel}: {why}") from exc
        if isinstance(self._bus, PacksAhead):
            for frame in self._idle_frames:
                self._bus.keep_packed(frame)
        if self.can_log is not None:
            self._log = TrafficLog(self.can_log)
        with self._cond:
            self._opened_ns = time.monotonic_ns()
        self._receiver_stop.clear()
        self._receiver = threading.Thread(target=self._receive_loop, name=f"odrive-can-rx-{self.node_id}", daemon=True)
        self._receiver.start()
        self._feeder_stop.clear()
        self._feeder = threading.Thread(target=self._feed_loop, name=f"odrive-can-{self.node_id}", daemon=True)
        self._feeder.start()

    def close(self) -> None:
        """Idle the motor, stop receiving, close the log and the bus. Idempotent, never raises."""
        if self._closed:
            return
        self.idle()
        self._feeder_stop.set()
        if self._feeder is not None:
            self._feeder.join(timeout=1.0)
            self._feeder = None
        self._receiver_stop.set()
        if self._receiver is not None:
            self._receiver.join(timeout=1.0)
            self._receiver = None
        if self._log is not None:
            self._log.stop()  # flushes the file
        if self._own_bus and self._bus is not None:
            with contextlib.suppress(Exception):
                self._bus.shutdown()
            self._bus = None
        self._closed = True

    def __enter__(self) -> OdriveCanMotor:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ sending
    def sink_failure(self) -> str | None:
        """Why the ``--can-log`` file stopped early (a full disk), or None."""
        log = self._log
        return log.failure if log is not None else None

    def _send(self, msg: can.Message) -> None:
        if self._bus is None:
            raise DeviceFault("CAN bus is not open")
        with self._tx_lock:
            try:
                self._bus.send(msg, timeout=0.1)
            except can.CanError as exc:
                raise DeviceFault(f"CAN send failed: {exc}") from exc
            self.tx_count += 1
            if self._log is not None:
                msg.timestamp = time.time()
                msg.is_rx = False
                msg.channel = getattr(self._bus, "channel_id", None) or self.channel
                self._log(msg)

    def send(self, message: cs.Message) -> None:
        """Send one CAN Simple message to this axis (no limit checks: prefer the Motor methods)."""
        self._send(cs.to_can(self.node_id, message, self.extended_id))

    def request(self, cmd: cs.Cmd) -> None:
        """Ask for a get message by RTR; the answer updates the driver's state when it arrives."""
        self._send(cs.request(self.node_id, cmd, self.extended_id))

    # ------------------------------------------------------------------ receiving (receive thread)
    def _receive_loop(self) -> None:
        """Wait for a frame, let others gather for RECEIVE_COALESCE_S, handle all that wait; until closed."""
        bus, stop = self._bus, self._receiver_stop
        assert bus is not None
        while not stop.is_set():
            try:
                frame = bus.recv(timeout=0.05)
                if frame is None:
                    continue
                stop.wait(RECEIVE_COALESCE_S)
                mono_minus_real = mono_minus_real_ns()
                now_ns = time.monotonic_ns()
                for _ in range(MAX_FRAMES_PER_WAKE):
                    if self._log is not None:
                        self._log(frame)
                    self._on_rx(frame, receive_ns(frame, now_ns, mono_minus_real))
                    frame = bus.recv(timeout=0.0)
                    if frame is None:
                        break
            except Exception as exc:  # e.g. the bus closing under us: recorded, never a traceback
                if stop.is_set():
                    return
                with contextlib.suppress(MemoryError):
                    self.rx_errors.append(f"{type(exc).__name__}: {exc}")
                time.sleep(0.01)  # a dead interface must not spin this thread; the heartbeat check reports it

    def _on_rx(self, frame: can.Message, host_ns: int | None = None) -> None:
        if host_ns is None:
            host_ns = time.monotonic_ns()
        try:
            node, msg = cs.parse_message(frame)
        except cs.CanParseError:
            with self._cond:
                self.parse_errors += 1
            return
        if node != self.node_id or isinstance(msg, cs.Request):
            return
        with self._cond:
            self.rx_count += 1
            if isinstance(msg, cs.Heartbeat):
                self._hb, self._hb_ns = msg, host_ns
                self._hb_count += 1
                self._hb_log.append((self._hb_count, host_ns, msg))
                self._cond.notify_all()
            elif isinstance(msg, cs.EncoderEstimates):
                self._pos, self._vel = msg.pos, msg.vel
                self._telemetry_ns = host_ns
                if self._streaming:
                    dev_t = frame.timestamp if frame.timestamp else host_ns * 1e-9
                    hb = self._hb
                    self._buffer(
                        (
                            host_ns,
                            dev_t,
                            msg.pos,
                            msg.vel,
                            self._setpoint,
                            self._iq,
                            self._vbus,
                            hb.axis_state if hb else 0,
                            hb.axis_error if hb else 0,
                        )
                    )
            elif isinstance(msg, cs.Iq):
                self._iq = msg.measured
            elif isinstance(msg, cs.BusVoltageCurrent):
                self._vbus, self._ibus = msg.voltage, msg.current
            elif isinstance(msg, cs.MotorError):
                self.motor_error = msg.error
                self._error_replies[cs.Cmd.GET_MOTOR_ERROR] += 1
                self._cond.notify_all()
            elif isinstance(msg, cs.EncoderError):
                self.encoder_error = msg.error
                self._error_replies[cs.Cmd.GET_ENCODER_ERROR] += 1
                self._cond.notify_all()
            elif isinstance(msg, cs.ControllerErrorMsg):
                self.controller_error = msg.error
                self._error_replies[cs.Cmd.GET_CONTROLLER_ERROR] += 1
                self._cond.notify_all()

    # ------------------------------------------------------------------ feeder thread
    def _feed_loop(self) -> None:
        """Feed the watchdog while armed, poll Iq and bus voltage, watch the heartbeat, on deadlines of its own;
        receiving holds the lock for one frame's bookkeeping at a time, so a flood cannot hold a feed back."""
        period = min(self.feed_period_s, self.poll_period_s)
        next_poll = next_wake = time.monotonic()
        asked_errors = False
        while not self._feeder_stop.wait(max(0.0, next_wake + period - time.monotonic())):
            next_wake = max(next_wake + period, time.monotonic() - period)  # late (a stall): no burst to catch up
            if self._tx_paused:
                continue
            now_ns = time.monotonic_ns()
            with self._cond:
                self._note_stall_locked(now_ns)
                self._stall.tick(now_ns)
                lost = self._heartbeat_lost_locked(now_ns)
                armed, setpoint, hb = self._armed, self._setpoint, self._hb
                if lost and armed and self._fault is None:
                    self._fault = lost
            try:
                if armed and not lost:
                    self.send(cs.SetInputVel(setpoint, 0.0))
                if time.monotonic() >= next_poll:
                    next_poll += self.poll_period_s
                    self.request(cs.Cmd.GET_IQ)
                    self.request(cs.Cmd.GET_BUS_VOLTAGE_CURRENT)
                flagged = hb is not None and (hb.motor_error_flag or hb.encoder_error_flag or hb.controller_error_flag)
                if flagged and not asked_errors:
                    for cmd in (cs.Cmd.GET_MOTOR_ERROR, cs.Cmd.GET_ENCODER_ERROR, cs.Cmd.GET_CONTROLLER_ERROR):
                        self.request(cmd)
                asked_errors = bool(flagged)
            except DeviceFault as exc:
                self.send_errors.append(str(exc))
            except Exception as exc:
                self.send_errors.append(f"{type(exc).__name__}: {exc}")

    def stop_feeding(self) -> None:
        """Fault injection: stop every periodic frame (watchdog feed and polls), as if the host had hung."""
        self._tx_paused = True

    def resume_feeding(self) -> None:
        self._tx_paused = False

    # ------------------------------------------------------------------ waiting on heartbeats
    def _note_stall_locked(self, now_ns: int) -> None:
        """A stall of this process since the feeder's last wake-up (:class:`HostStall`), under the lock."""
        self._stall.note(now_ns, self._armed, self.heartbeat_timeout_s, self.timing.watchdog_timeout_s)

    def _stall_text(self) -> str:
        return self._stall.text(f"ODrive node {self.node_id}", self.timing.watchdog_timeout_s)

    def _heartbeat_lost_locked(self, now_ns: int) -> str | None:
        if self._opened_ns is None:
            return None
        self._note_stall_locked(now_ns)
        limit_ns = int(self.heartbeat_timeout_s * 1e9)
        if self._hb_ns is None:
            if now_ns - self._opened_ns > limit_ns:
                return f"no heartbeat from ODrive node {self.node_id} on {self.interface}:{self.channel}"
            return None
        age = now_ns - self._hb_ns
        if age > limit_ns and self._stall.stall_ns:
            return self._stall_text()
        if age > limit_ns:
            limit_ms = self.heartbeat_timeout_s * 1e3
            return f"ODrive node {self.node_id} heartbeat lost for {age / 1e6:.0f} ms (> {limit_ms:.0f} ms)"
        return None

    def _telemetry_silent_locked(self, now_ns: int) -> str | None:
        """Encoder_Estimates (cyclic, 10 ms by default) stopped while streaming, though heartbeats may still come."""
        timeout = self.telemetry_timeout_s
        if timeout is None or not self._streaming or self._streaming_ns is None:
            return None
        last = max(self._telemetry_ns or 0, self._streaming_ns)
        if now_ns - last > timeout * 1e9:
            return (
                f"ODrive node {self.node_id}: no encoder estimates for {(now_ns - last) * 1e-9:.2f} s (> {timeout:g} s)"
            )
        return None

    def health(self) -> dict[str, Any]:
        """Counters for the session: telemetry rows received, CAN frames that failed to parse, send errors; and
        what a transport that accepts only the device's endpoint refused (``forged``; on a real CAN bus any
        node may send, so 0), dropped unread (``kernel_dropped``) and the flood it names (``flood``)."""
        bus = self._bus
        forged, garbled = (bus.forged, bus.garbled) if isinstance(bus, RefusesForeign) else (0, 0)
        flood: dict[str, Any] = (
            {"kernel_dropped": bus.kernel_dropped, "flood": bus.flood()} if isinstance(bus, RefusesForeign) else {}
        )
        with self._cond:
            return {
                "received": self.rows_received,
                "unrecorded": len(self._rows),  # received, never read (arrived while the run closed)
                # CAN Simple frames carry no sequence number: losses on the bus cannot be counted; rows a full
                # buffer evicted can
                "dropped": self.rows_evicted,
                "garbled": self.parse_errors + garbled,
                "forged": forged,
                **flood,
                "frames_received": self.rx_count,
                "frames_sent": self.tx_count,
                "send_errors": len(self.send_errors),
                "fault": self._fault or "",
            }

    def _wait_heartbeat(self, pred, timeout_s: float, after_ns: int) -> cs.Heartbeat | None:
        """First heartbeat received after ``after_ns`` satisfying ``pred`` (or None on timeout)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            seen = 0
            while True:
                for count, hb_ns, hb in self._hb_log:  # every heartbeat since the last look, in order
                    if count > seen:
                        seen = count
                        if hb_ns > after_ns and pred(hb):
                            return hb
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)

    def read_error_registers(self, hb: cs.Heartbeat | None = None) -> None:
        """Ask for the motor/encoder/controller error registers the heartbeat flags and wait (at most
        ``error_read_timeout_s``) for the answers, so a fault report names the error the ODrive latched rather
        than the last value read (0 before the first fault). Never raises; call without holding the lock."""
        hb = hb or self.heartbeat
        if hb is None or self._bus is None or self._closed:
            return
        flags = (hb.motor_error_flag, hb.encoder_error_flag, hb.controller_error_flag)
        wanted = [cmd for cmd, flag in zip(_ERROR_REGISTERS, flags) if flag]
        if not wanted:
            return
        with self._cond:
            before = {cmd: self._error_replies[cmd] for cmd in wanted}
        try:
            for cmd in wanted:
                self.request(cmd)
        except Exception as exc:
            self.send_errors.append(f"error registers: {exc}")
            return
        deadline = time.monotonic() + self.error_read_timeout_s
        with self._cond:
            while any(self._error_replies[c] == before[c] for c in wanted):
                left = deadline - time.monotonic()
                if left <= 0:
                    return
                self._cond.wait(left)

    def _describe_fault(self, hb: cs.Heartbeat) -> str:
        """The fault text after reading the error registers it needs (not under the lock)."""
        self.read_error_registers(hb)
        return self._fault_text(hb)

    def _fault_text(self, hb: cs.Heartbeat) -> str:
        parts = [f"axis error {cs.error_names(hb.axis_error)}"]
        if hb.motor_error_flag or self.motor_error:
            parts.append(f"motor error {self.motor_error:#x}")
        if hb.encoder_error_flag or self.encoder_error:
            parts.append(f"encoder error {self.encoder_error:#x}")
        if hb.controller_error_flag or self.controller_error:
            parts.append(f"controller error {cs.error_names(self.controller_error, cs.ControllerError)}")
        state = AxisState(hb.axis_state).name if hb.axis_state in AxisState._value2member_map_ else hb.axis_state
        return f"ODrive node {self.node_id}: " + ", ".join(parts) + f" (state {state})"

    # ------------------------------------------------------------------ Motor protocol (stream: TelemetryStream)
    def arm(self, limits: MotorLimits) -> None:
        """Limits, velocity-ramp mode, watchdog feed, (calibration,) closed loop at 0 turn/s."""
        vel_limit = vel_limit_for(limits)
        current = current_limit_for(limits)
        self.open()
        t0 = time.monotonic_ns()
        if self._wait_heartbeat(lambda hb: True, max(1.0, 3 * self.heartbeat_timeout_s), t0 - 10**9) is None:
            raise DeviceFault(f"no heartbeat from ODrive node {self.node_id} on {self.interface}:{self.channel}")
        with self._cond:
            self._fault = None
            self._stall.stall_ns = 0
            self._limits = limits
            self._setpoint = 0.0
        self.vel_limit, self.current_limit = vel_limit, current
        try:
            cleared = time.monotonic_ns()
            self.send(cs.ClearErrors())
            hb = self._wait_heartbeat(lambda h: h.axis_error == 0, max(0.5, 3 * self.heartbeat_timeout_s), cleared)
            if hb is None:
                self._raise_if_lost(cleared, "Clear_Errors")
                last = self.heartbeat
                raise DeviceFault("errors persist after Clear_Errors: " + (self._describe_fault(last) if last else "?"))
            self.send(cs.SetLimits(vel_limit, current))
            self.send(cs.SetControllerMode(ControlMode.VELOCITY_CONTROL, InputMode.VEL_RAMP))
            self.send(cs.SetInputVel(0.0, 0.0))
            if self.calibrate:
                self._calibrate()
            with self._cond:
                self._armed = True  # the feeder now feeds the watchdog
            sent = time.monotonic_ns()
            self.send(cs.SetAxisState(AxisState.CLOSED_LOOP_CONTROL))
            hb = self._wait_heartbeat(
                lambda h: h.axis_state == AxisState.CLOSED_LOOP_CONTROL or h.axis_error != 0,
                self.closed_loop_timeout_s,
                sent,
            )
            if hb is None:
                self._raise_if_lost(sent, "the closed-loop request")
                raise DeviceFault(
                    f"ODrive node {self.node_id} did not enter closed loop within {self.closed_loop_timeout_s:g} s"
                )
            if hb.axis_error:
                raise DeviceFault("entering closed loop failed: " + self._describe_fault(hb))
        except BaseException:
            self.idle()
            raise

    def _raise_if_lost(self, since_ns: int, what: str) -> None:
        """A wait for an answer ran out: if no heartbeat came at all since ``since_ns``, say the link is lost
        (the last heartbeat's state, from before, would describe an ODrive that is no longer there)."""
        with self._cond:
            hb_ns = self._hb_ns
        if hb_ns is None or hb_ns <= since_ns:
            quiet = (time.monotonic_ns() - (hb_ns or since_ns)) * 1e-9
            raise DeviceFault(
                f"ODrive node {self.node_id}: no heartbeat for {quiet:.1f} s since {what} "
                f"({self.interface}:{self.channel}): the ODrive or its link is lost"
            )

    def _calibrate(self) -> None:
        sent = time.monotonic_ns()
        self.send(cs.SetAxisState(AxisState.FULL_CALIBRATION_SEQUENCE))
        startup = max(0.5, 4 * self.heartbeat_timeout_s)
        hb = self._wait_heartbeat(lambda h: h.axis_state != AxisState.IDLE or h.axis_error != 0, startup, sent)
        if hb is None:
            self._raise_if_lost(sent, "the calibration request")
            raise DeviceFault(f"ODrive node {self.node_id} did not start calibrating")
        if hb.axis_error == 0:
            deadline = time.monotonic() + self.calibration_timeout_s
            hb = None
            while hb is None and time.monotonic() < deadline:  # in heartbeat timeouts: a lost ODrive is said at once
                t = time.monotonic_ns()
                wait = min(max(0.5, self.heartbeat_timeout_s), max(0.0, deadline - time.monotonic()))
                hb = self._wait_heartbeat(lambda h: h.axis_state == AxisState.IDLE or h.axis_error != 0, wait, t)
                if hb is None:
                    self._raise_if_lost(t, "the calibration started")
            if hb is None:
                raise DeviceFault(
                    f"ODrive node {self.node_id} calibration did not finish in {self.calibration_timeout_s:g} s"
                )
        if hb.axis_error:
            raise DeviceFault("calibration failed: " + self._describe_fault(hb))

    def set_frequency(self, hz: float) -> None:
        """Crank at ``hz`` turn/s; LimitError above ``max_frequency_hz`` (nothing is sent)."""
        limits = self._limits
        if not math.isfinite(hz):
            raise LimitError(f"frequency {hz!r} is not a number")
        if limits is None or not self._armed:
            raise DeviceFault("set_frequency() before arm()")
        if abs(hz) > limits.max_frequency_hz:
            raise LimitError(f"frequency {hz:g} Hz exceeds limits.max_frequency_hz = {limits.max_frequency_hz:g}")
        with self._cond:
            self._setpoint = float(hz)
        self.send(cs.SetInputVel(float(hz), 0.0))

    def idle(self) -> None:
        """Set_Axis_State IDLE and input velocity 0, from frames built at construction (no allocation needed),
        each tried ``IDLE_SEND_TRIES`` times. Idempotent; never raises (errors kept in ``send_errors``)."""
        with self._cond:
            self._armed = False
            self._setpoint = 0.0
        if self._bus is None or self._closed:
            return
        self._idle_sent_ns = time.monotonic_ns()
        for frame in self._idle_frames:
            for attempt in range(IDLE_SEND_TRIES):
                try:
                    self._send(frame)
                    break
                except BaseException as exc:  # MemoryError included: the next try may find memory freed
                    if attempt == IDLE_SEND_TRIES - 1:
                        with contextlib.suppress(BaseException):
                            self.send_errors.append(f"idle: {exc}")
                    else:
                        time.sleep(IDLE_RETRY_S)

    def confirm_idle(self) -> str:
        """After :meth:`idle`: "motor idle" once a heartbeat sent after it says AXIS_STATE_IDLE (waiting at most
        ``timing.idle_confirm_s``); otherwise "idle NOT confirmed" and when the ODrive's watchdog idles it."""
        sent = self._idle_sent_ns
        if sent is not None and self._bus is not None:
            hb = self._wait_heartbeat(lambda h: h.axis_state == AxisState.IDLE, self.timing.idle_confirm_s, sent)
            if hb is not None:
                return f"motor idle (ODrive node {self.node_id} confirms AXIS_STATE_IDLE)"
        return idle_not_confirmed(self.timing.watchdog_timeout_s)

    def estop(self) -> None:
        """Send Estop: the axis latches ESTOP_REQUESTED and goes idle until errors are cleared."""
        with self._cond:
            self._armed = False
            self._setpoint = 0.0
        self.send(cs.Estop())

    def clear_errors(self) -> None:
        self.send(cs.ClearErrors())

    def check(self) -> None:
        """Raise DeviceFault on axis errors, on leaving closed loop while armed, or on a lost heartbeat."""
        with self._cond:
            lost = self._heartbeat_lost_locked(time.monotonic_ns())
            if self._stall.stall_ns and self._armed:  # whatever the ODrive says now follows from the host's stall
                raise DeviceFault(self._stall_text())
            if self._fault is not None:
                raise DeviceFault(self._fault)
            if lost is not None:
                raise DeviceFault(lost)
            hb, armed = self._hb, self._armed
            silent = self._telemetry_silent_locked(time.monotonic_ns())
        if silent is not None:
            raise DeviceFault(silent)
        if hb is None:
            return
        if hb.axis_error or hb.motor_error_flag or hb.encoder_error_flag or hb.controller_error_flag:
            raise DeviceFault(self._describe_fault(hb))  # the registers are read first, then reported
        if armed and hb.axis_state != AxisState.CLOSED_LOOP_CONTROL:
            raise DeviceFault(f"ODrive node {self.node_id} left closed loop (state {hb.axis_state})")

    # ------------------------------------------------------------------ info
    @property
    def heartbeat(self) -> cs.Heartbeat | None:
        with self._cond:
            return self._hb

    def latest(self) -> dict[str, float]:
        """Latest received values (NaN before the first)."""
        with self._cond:
            return {
                "position": self._pos,
                "velocity": self._vel,
                "iq_measured": self._iq,
                "bus_voltage": self._vbus,
                "bus_current": self._ibus,
                "setpoint": self._setpoint,
            }

    def identity(self) -> dict[str, Any]:
        return {
            "driver": "beambench.devices.odrive.can_motor.OdriveCanMotor",
            "protocol": "ODrive CAN Simple (firmware 0.5.x)",
            "interface": self.interface,
            "channel": self.channel,
            "node_id": self.node_id,
            "vel_limit_turn_s": self.vel_limit,
            "current_limit_a": self.current_limit,
            "can_log": str(self.can_log) if self.can_log else None,
            "note": "CAN Simple 0.5.x reports no serial number or firmware version",
        }
