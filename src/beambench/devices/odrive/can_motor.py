"""ODrive v3.6 (firmware 0.5.x) over CAN Simple with python-can, behind :class:`beambench.acquisition.capabilities.Motor`.

The crank turns once per stage cycle, so a step at frequency f Hz is a velocity of f turn/s.

Safety, in the order :meth:`OdriveCanMotor.arm` does it:

1. the limits are checked on the host first: ``vel_limit = max_frequency_hz × 1.1`` (a little headroom so
   the velocity loop's ripple does not hit the limit) and ``current_lim = max_current_a``
   (:mod:`~beambench.devices.odrive.limits`); a velocity limit above ``MAX_VEL_LIMIT`` is refused (the lab's old
   script set 8000 turn/s, which disables the limit);
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
timestamp (the interface's receive time — the kernel's for socketcan, the host's for the loopback bus, the
sender's for the virtual bus; host receive time if the interface gives none) and ``host_time_ns`` is that same
time on the monotonic clock when it is a recent wall-clock time
(:func:`~beambench.devices.odrive.can_link.receive_ns`), else ``time.monotonic_ns()`` when the driver handled
the frame.

The class composes the driver's jobs: the bus, its receive thread and the ``can_log`` traffic file
(:class:`~beambench.devices.odrive.can_link.CanLink`; python-can's own ``can.Logger``, .asc or .blf or another
python-can format), what the axis reported and what was commanded
(:class:`~beambench.devices.odrive.can_axis.AxisView`), and the watchdog feeder with the liveness checks
(:class:`~beambench.devices.odrive.can_watch.AxisWatch`); it does the arming and idling sequences and the stream.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can

from beambench.acquisition.capabilities import DeviceFault, MotorLimits, RefusesForeign
from beambench.acquisition.streams import MOTOR
from beambench.devices.odrive import cansimple as cs
from beambench.devices.odrive.can_axis import AxisView
from beambench.devices.odrive.can_link import CanLink
from beambench.devices.odrive.can_timing import CanMotorTiming
from beambench.devices.odrive.can_watch import AxisWatch
from beambench.devices.odrive.cansimple import AxisState, ControlMode, InputMode
from beambench.devices.odrive.host_stall import idle_not_confirmed
from beambench.devices.odrive.limits import LimitError, current_limit_for, vel_limit_for
from beambench.devices.odrive.telemetry import MAX_BUFFERED_ROWS, TelemetryStream

DEFAULT_TIMING = CanMotorTiming()
IDLE_SEND_TRIES = 5  # each idle frame is sent up to this many times (a full TX queue, no memory for a moment)
IDLE_RETRY_S = 0.02


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
        self.channel, self.interface, self.node_id, self.bitrate = channel, interface, node_id, bitrate
        self.can_log = Path(can_log) if can_log is not None else None
        own = bus is None if own_bus is None else own_bus
        self.link = CanLink(
            node_id, interface, channel, bitrate, bus=bus, own_bus=own, can_log=self.can_log, extended_id=extended_id
        )
        self.timing = timing
        self.heartbeat_timeout_s = timing.heartbeat_timeout_s
        self.view = AxisView(node_id)
        self.watch = AxisWatch(self.link, self.view, timing)
        self._cond = self.view.cond  # guards the view, the watch's state and the stream's rows
        self._guard = self._cond
        self._limits: MotorLimits | None = None
        self.vel_limit: float | None = None
        self.current_limit: float | None = None
        self._streaming = False
        self._rows: deque[tuple] = deque(maxlen=MAX_BUFFERED_ROWS)
        self.rows_received = self.rows_evicted = 0  # TelemetryStream._buffer counts them
        self._streaming_ns: int | None = None  # when the telemetry stream started
        self._closed = False
        # the idle frames, built now: sending them must not need memory the run may have run out of
        self._idle_sent_ns: int | None = None
        self._idle_frames = tuple(
            cs.to_can(node_id, m, extended_id) for m in (cs.SetAxisState(AxisState.IDLE), cs.SetInputVel(0.0, 0.0))
        )

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> None:
        """Open the bus, start receiving (and logging), feeding and polling. Idempotent."""
        if self.link.receiving:
            return
        if self._closed:
            raise DeviceFault("OdriveCanMotor is closed")
        self.link.open(self.receive, f"odrive-can-rx-{self.node_id}", keep_packed=self._idle_frames)
        self.watch.start()

    def close(self) -> None:
        """Idle the motor, stop feeding and receiving, close the log and the bus. Idempotent, never raises."""
        if self._closed:
            return
        self.idle()
        self.watch.stop()
        self.link.close()
        self._closed = True

    def __enter__(self) -> OdriveCanMotor:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def sink_failure(self) -> str | None:
        """Why the ``--can-log`` file stopped early (a full disk), or None."""
        return self.link.sink_failure()

    def send(self, message: cs.Message) -> None:
        """Send one CAN Simple message to this axis (no limit checks: prefer the Motor methods)."""
        self.link.send_message(message)

    def request(self, cmd: cs.Cmd) -> None:
        """Ask for a get message by RTR; the answer updates the driver's state when it arrives."""
        self.link.request(cmd)

    def receive(self, frame: can.Message, host_ns: int | None = None) -> None:
        """Handle one frame from the bus (the link's receive thread calls this; ``host_ns``: when it arrived, on
        the monotonic clock): the view keeps it; an Encoder_Estimates is a telemetry row while streaming."""
        if host_ns is None:
            host_ns = time.monotonic_ns()
        msg = self.view.parse(frame)
        if msg is None:
            return
        with self._cond:
            self.view.keep(msg, host_ns)
            if isinstance(msg, cs.EncoderEstimates) and self._streaming:
                self._buffer(self._row(msg, host_ns, frame.timestamp))

    def _row(self, msg: cs.EncoderEstimates, host_ns: int, stamp: float) -> tuple:
        """The telemetry row of one Encoder_Estimates (see :func:`rows_to_batch`), under the lock."""
        view, hb = self.view, self.view.hb
        dev_t = stamp if stamp else host_ns * 1e-9
        state, error = (hb.axis_state, hb.axis_error) if hb else (0, 0)
        return (host_ns, dev_t, msg.pos, msg.vel, view.setpoint, view.iq, view.vbus, state, error)

    # ------------------------------------------------------------------ Motor protocol (stream: TelemetryStream)
    def arm(self, limits: MotorLimits) -> None:
        """Limits, velocity-ramp mode, watchdog feed, (calibration,) closed loop at 0 turn/s."""
        vel_limit = vel_limit_for(limits)
        current = current_limit_for(limits)
        self.open()
        t0 = time.monotonic_ns()
        if self._wait(lambda hb: True, max(1.0, 3 * self.heartbeat_timeout_s), t0 - 10**9) is None:
            raise DeviceFault(f"no heartbeat from ODrive node {self.node_id} on {self.interface}:{self.channel}")
        with self._cond:
            self.watch.rearm()
            self._limits = limits
            self.view.setpoint = 0.0
        self.vel_limit, self.current_limit = vel_limit, current
        try:
            cleared = time.monotonic_ns()
            self.send(cs.ClearErrors())
            hb = self._wait(lambda h: h.axis_error == 0, max(0.5, 3 * self.heartbeat_timeout_s), cleared)
            if hb is None:
                self.watch.raise_if_lost(cleared, "Clear_Errors")
                last = self.heartbeat
                raise DeviceFault("errors persist after Clear_Errors: " + (self._describe(last) if last else "?"))
            self.send(cs.SetLimits(vel_limit, current))
            self.send(cs.SetControllerMode(ControlMode.VELOCITY_CONTROL, InputMode.VEL_RAMP))
            self.send(cs.SetInputVel(0.0, 0.0))
            if self.timing.calibrate:
                self._calibrate()
            with self._cond:
                self.view.armed = True  # the feeder now feeds the watchdog
            self._enter_closed_loop()
        except BaseException:
            self.idle()
            raise

    def _wait(self, pred: Callable[[cs.Heartbeat], bool], timeout_s: float, after_ns: int) -> cs.Heartbeat | None:
        return self.view.wait_heartbeat(pred, timeout_s, after_ns)

    def _describe(self, hb: cs.Heartbeat) -> str:
        return self.watch.describe_fault(hb)

    def _enter_closed_loop(self) -> None:
        sent = time.monotonic_ns()
        self.send(cs.SetAxisState(AxisState.CLOSED_LOOP_CONTROL))
        timeout = self.timing.closed_loop_timeout_s
        hb = self._wait(lambda h: h.axis_state == AxisState.CLOSED_LOOP_CONTROL or h.axis_error != 0, timeout, sent)
        if hb is None:
            self.watch.raise_if_lost(sent, "the closed-loop request")
            raise DeviceFault(f"ODrive node {self.node_id} did not enter closed loop within {timeout:g} s")
        if hb.axis_error:
            raise DeviceFault("entering closed loop failed: " + self._describe(hb))

    def _calibrate(self) -> None:
        sent = time.monotonic_ns()
        self.send(cs.SetAxisState(AxisState.FULL_CALIBRATION_SEQUENCE))
        startup = max(0.5, 4 * self.heartbeat_timeout_s)
        hb = self._wait(lambda h: h.axis_state != AxisState.IDLE or h.axis_error != 0, startup, sent)
        if hb is None:
            self.watch.raise_if_lost(sent, "the calibration request")
            raise DeviceFault(f"ODrive node {self.node_id} did not start calibrating")
        if hb.axis_error == 0:
            timeout = self.timing.calibration_timeout_s
            deadline = time.monotonic() + timeout
            hb = None
            while hb is None and time.monotonic() < deadline:  # in heartbeat timeouts: a lost ODrive is said at once
                t = time.monotonic_ns()
                wait = min(max(0.5, self.heartbeat_timeout_s), max(0.0, deadline - time.monotonic()))
                hb = self._wait(lambda h: h.axis_state == AxisState.IDLE or h.axis_error != 0, wait, t)
                if hb is None:
                    self.watch.raise_if_lost(t, "the calibration started")
            if hb is None:
                raise DeviceFault(f"ODrive node {self.node_id} calibration did not finish in {timeout:g} s")
        if hb.axis_error:
            raise DeviceFault("calibration failed: " + self._describe(hb))

    def set_frequency(self, hz: float) -> None:
        """Crank at ``hz`` turn/s; LimitError above ``max_frequency_hz`` (nothing is sent)."""
        limits = self._limits
        if not math.isfinite(hz):
            raise LimitError(f"frequency {hz!r} is not a number")
        if limits is None or not self.view.armed:
            raise DeviceFault("set_frequency() before arm()")
        if abs(hz) > limits.max_frequency_hz:
            raise LimitError(f"frequency {hz:g} Hz exceeds limits.max_frequency_hz = {limits.max_frequency_hz:g}")
        with self._cond:
            self.view.setpoint = float(hz)
        self.send(cs.SetInputVel(float(hz), 0.0))

    def idle(self) -> None:
        """Set_Axis_State IDLE and input velocity 0, from frames built at construction (no allocation needed),
        each tried ``IDLE_SEND_TRIES`` times. Idempotent; never raises (errors kept in ``send_errors``)."""
        with self._cond:
            self.view.armed = False
            self.view.setpoint = 0.0
        if self.link.bus is None or self._closed:
            return
        self._idle_sent_ns = time.monotonic_ns()
        for frame in self._idle_frames:
            for attempt in range(IDLE_SEND_TRIES):
                try:
                    self.link.send(frame)
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
        if sent is not None and self.link.bus is not None:
            hb = self._wait(lambda h: h.axis_state == AxisState.IDLE, self.timing.idle_confirm_s, sent)
            if hb is not None:
                return f"motor idle (ODrive node {self.node_id} confirms AXIS_STATE_IDLE)"
        return idle_not_confirmed(self.timing.watchdog_timeout_s)

    def estop(self) -> None:
        """Send Estop: the axis latches ESTOP_REQUESTED and goes idle until errors are cleared."""
        with self._cond:
            self.view.armed = False
            self.view.setpoint = 0.0
        self.send(cs.Estop())

    def clear_errors(self) -> None:
        self.send(cs.ClearErrors())

    def check(self) -> None:
        """Raise DeviceFault on axis errors, on leaving closed loop while armed, or on a lost heartbeat."""
        with self._cond:
            streaming_ns = self._streaming_ns if self._streaming else None
        self.watch.check(streaming_ns)

    def stop_feeding(self) -> None:
        """Fault injection: stop every periodic frame (watchdog feed and polls), as if the host had hung."""
        self.watch.paused = True

    def resume_feeding(self) -> None:
        self.watch.paused = False

    # ------------------------------------------------------------------ info
    @property
    def heartbeat(self) -> cs.Heartbeat | None:
        with self._cond:
            return self.view.hb

    @property
    def idle_sent_ns(self) -> int | None:
        """When :meth:`idle` last sent its frames (host monotonic ns); None before it has."""
        return self._idle_sent_ns

    @property
    def tx_count(self) -> int:
        """Frames sent."""
        return self.link.tx_count

    @property
    def send_errors(self) -> deque[str]:
        """Sends that failed where no caller could be told (the feeder's, the idle's)."""
        return self.link.send_errors

    def latest(self) -> dict[str, float]:
        """Latest received values (NaN before the first)."""
        return self.view.latest()

    def health(self) -> dict[str, Any]:
        """Counters for the session: telemetry rows received, CAN frames that failed to parse, send errors; and
        what a transport that accepts only the device's endpoint refused (``forged``; on a real CAN bus any
        node may send, so 0), dropped unread (``kernel_dropped``) and the flood it names (``flood``)."""
        bus = self.link.bus
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
                "garbled": self.view.parse_errors + garbled,
                "forged": forged,
                **flood,
                "frames_received": self.view.rx_count,
                "frames_sent": self.link.tx_count,
                "send_errors": len(self.link.send_errors),
                "fault": self.watch.fault or "",
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
