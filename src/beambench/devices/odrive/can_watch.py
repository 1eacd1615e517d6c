"""Supervision of one ODrive axis over CAN: a feeder thread that feeds the firmware watchdog while the axis is
armed and polls Iq and bus voltage, and the liveness checks — heartbeat lost, telemetry silent, the host's own
stall — with the fault reports that name the error registers' values.

Every frame to the axis feeds the firmware watchdog; CAN Simple 0.5.x has no message to *enable* it (that is
set once over USB). The feeder stops feeding when the heartbeat is lost, so a half-broken link lets the
ODrive's own watchdog idle the motor.
"""

from __future__ import annotations

import threading
import time

from beambench.acquisition.capabilities import DeviceFault
from beambench.devices.odrive import cansimple as cs
from beambench.devices.odrive.can_axis import ERROR_REGISTERS, AxisView, flagged_registers
from beambench.devices.odrive.can_link import CanLink
from beambench.devices.odrive.can_timing import CanMotorTiming
from beambench.devices.odrive.cansimple import AxisState
from beambench.devices.odrive.host_stall import HostStall


class AxisWatch:
    """Feeds, polls and watches the axis that ``view`` describes over ``link``, as ``timing`` says. Its own state
    (``fault``, ``stall``, ``opened_ns``) is guarded by ``view.cond``."""

    def __init__(self, link: CanLink, view: AxisView, timing: CanMotorTiming) -> None:
        self.link, self.view, self.timing = link, view, timing
        self.node = f"ODrive node {link.node_id}"
        self.error_read_timeout_s = 0.25  # how long a fault report waits for the error registers' answers
        self.opened_ns: int | None = None  # when the link opened (a first heartbeat is due within the timeout)
        self.fault: str | None = None  # a loss the feeder saw while armed, kept until the next arm
        self.stall = HostStall()  # the host's own stall (no CPU time), not the ODrive's silence
        self.paused = False  # fault injection: no periodic frame at all, as if the host had hung
        self._feeder: threading.Thread | None = None
        self._feeder_stop = threading.Event()

    # ------------------------------------------------------------------ the feeder thread
    def start(self) -> None:
        """The link is open: a heartbeat is due from now on; start feeding and polling."""
        with self.view.cond:
            self.opened_ns = time.monotonic_ns()
        self._feeder_stop.clear()
        self._feeder = threading.Thread(target=self._feed_loop, name=f"odrive-can-{self.link.node_id}", daemon=True)
        self._feeder.start()

    def stop(self) -> None:
        self._feeder_stop.set()
        if self._feeder is not None:
            self._feeder.join(timeout=1.0)
            self._feeder = None

    def rearm(self) -> None:
        """Arming starts afresh: no fault kept, no stall seen (the caller holds ``view.cond``)."""
        self.fault = None
        self.stall.stall_ns = 0

    def _feed_loop(self) -> None:
        """Feed the watchdog while armed, poll Iq and bus voltage, watch the heartbeat, on deadlines of its own;
        receiving holds the lock for one frame's bookkeeping at a time, so a flood cannot hold a feed back."""
        period = min(self.timing.feed_period_s, self.timing.poll_period_s)
        next_poll = next_wake = time.monotonic()
        asked_errors = False
        view, link = self.view, self.link
        while not self._feeder_stop.wait(max(0.0, next_wake + period - time.monotonic())):
            next_wake = max(next_wake + period, time.monotonic() - period)  # late (a stall): no burst to catch up
            if self.paused:
                continue
            now_ns = time.monotonic_ns()
            with view.cond:
                self._note_stall_locked(now_ns)
                self.stall.tick(now_ns)
                lost = self.heartbeat_lost_locked(now_ns)
                armed, setpoint, hb = view.armed, view.setpoint, view.hb
                if lost and armed and self.fault is None:
                    self.fault = lost
            try:
                if armed and not lost:
                    link.send_message(cs.SetInputVel(setpoint, 0.0))
                if time.monotonic() >= next_poll:
                    next_poll += self.timing.poll_period_s
                    link.request(cs.Cmd.GET_IQ)
                    link.request(cs.Cmd.GET_BUS_VOLTAGE_CURRENT)
                flagged = hb is not None and bool(flagged_registers(hb))
                if flagged and not asked_errors:
                    for cmd in ERROR_REGISTERS:
                        link.request(cmd)
                asked_errors = flagged
            except DeviceFault as exc:
                link.send_errors.append(str(exc))
            except Exception as exc:
                link.send_errors.append(f"{type(exc).__name__}: {exc}")

    # ------------------------------------------------------------------ liveness (under view.cond)
    def _note_stall_locked(self, now_ns: int) -> None:
        """A stall of this process since the feeder's last wake-up (:class:`HostStall`)."""
        timing = self.timing
        self.stall.note(now_ns, self.view.armed, timing.heartbeat_timeout_s, timing.watchdog_timeout_s)

    def stall_text(self) -> str:
        return self.stall.text(self.node, self.timing.watchdog_timeout_s)

    def heartbeat_lost_locked(self, now_ns: int) -> str | None:
        """Why the heartbeat counts as lost (none since the link opened, or none for too long), or None."""
        if self.opened_ns is None:
            return None
        self._note_stall_locked(now_ns)
        limit_ns = int(self.timing.heartbeat_timeout_s * 1e9)
        hb_ns = self.view.hb_ns
        if hb_ns is None:
            if now_ns - self.opened_ns > limit_ns:
                return f"no heartbeat from {self.node} on {self.link.interface}:{self.link.channel}"
            return None
        age = now_ns - hb_ns
        if age > limit_ns and self.stall.stall_ns:
            return self.stall_text()
        if age > limit_ns:
            limit_ms = self.timing.heartbeat_timeout_s * 1e3
            return f"{self.node} heartbeat lost for {age / 1e6:.0f} ms (> {limit_ms:.0f} ms)"
        return None

    def telemetry_silent_locked(self, now_ns: int, streaming_ns: int | None) -> str | None:
        """Encoder_Estimates (cyclic, 10 ms by default) stopped while streaming (since ``streaming_ns``; None: not
        streaming), though heartbeats may still come."""
        timeout = self.timing.telemetry_timeout_s
        if timeout is None or streaming_ns is None:
            return None
        last = max(self.view.telemetry_ns or 0, streaming_ns)
        if now_ns - last > timeout * 1e9:
            return f"{self.node}: no encoder estimates for {(now_ns - last) * 1e-9:.2f} s (> {timeout:g} s)"
        return None

    # ------------------------------------------------------------------ checks and fault reports
    def check(self, streaming_ns: int | None) -> None:
        """Raise DeviceFault on a host stall while armed, a kept fault, a lost heartbeat, silent telemetry
        (``streaming_ns``: when streaming started, None if not), axis errors, or leaving closed loop while armed."""
        view = self.view
        with view.cond:
            lost = self.heartbeat_lost_locked(time.monotonic_ns())
            if self.stall.stall_ns and view.armed:  # whatever the ODrive says now follows from the host's stall
                raise DeviceFault(self.stall_text())
            if self.fault is not None:
                raise DeviceFault(self.fault)
            if lost is not None:
                raise DeviceFault(lost)
            hb, armed = view.hb, view.armed
            silent = self.telemetry_silent_locked(time.monotonic_ns(), streaming_ns)
        if silent is not None:
            raise DeviceFault(silent)
        if hb is None:
            return
        if hb.axis_error or flagged_registers(hb):
            raise DeviceFault(self.describe_fault(hb))  # the registers are read first, then reported
        if armed and hb.axis_state != AxisState.CLOSED_LOOP_CONTROL:
            raise DeviceFault(f"{self.node} left closed loop (state {hb.axis_state})")

    def read_error_registers(self, hb: cs.Heartbeat) -> None:
        """Ask for the motor/encoder/controller error registers the heartbeat flags and wait (at most
        ``error_read_timeout_s``) for the answers, so a fault report names the error the ODrive latched rather
        than the last value read (0 before the first fault). Never raises; call without holding the lock."""
        wanted = flagged_registers(hb)
        if not wanted or self.link.bus is None or self.link.closed:
            return
        with self.view.cond:
            before = {cmd: self.view.error_replies[cmd] for cmd in wanted}
        try:
            for cmd in wanted:
                self.link.request(cmd)
        except Exception as exc:
            self.link.send_errors.append(f"error registers: {exc}")
            return
        self.view.wait_replies(before, self.error_read_timeout_s)

    def describe_fault(self, hb: cs.Heartbeat) -> str:
        """The fault text after reading the error registers it needs (not under the lock)."""
        self.read_error_registers(hb)
        return self.view.fault_text(hb)

    def raise_if_lost(self, since_ns: int, what: str) -> None:
        """A wait for an answer ran out: if no heartbeat came at all since ``since_ns``, say the link is lost
        (the last heartbeat's state, from before, would describe an ODrive that is no longer there)."""
        with self.view.cond:
            hb_ns = self.view.hb_ns
        if hb_ns is None or hb_ns <= since_ns:
            quiet = (time.monotonic_ns() - (hb_ns or since_ns)) * 1e-9
            raise DeviceFault(
                f"{self.node}: no heartbeat for {quiet:.1f} s since {what} "
                f"({self.link.interface}:{self.link.channel}): the ODrive or its link is lost"
            )
