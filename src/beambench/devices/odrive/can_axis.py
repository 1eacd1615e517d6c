"""One ODrive axis as the CAN driver knows it: what its frames reported (heartbeats, encoder estimates, Iq, bus
voltage and current, the error registers' answers) and what the host commanded (armed, the setpoint), all under
one condition variable that waiters on a heartbeat or a register's answer sleep on."""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable

import can

from beambench.devices.odrive import cansimple as cs
from beambench.devices.odrive.cansimple import AxisState

ERROR_REGISTERS = (cs.Cmd.GET_MOTOR_ERROR, cs.Cmd.GET_ENCODER_ERROR, cs.Cmd.GET_CONTROLLER_ERROR)
HEARTBEAT_LOG = 64  # heartbeats kept for waiters: 6 s at the default 100 ms


def flagged_registers(hb: cs.Heartbeat) -> list[cs.Cmd]:
    """The error registers (motor, encoder, controller) a heartbeat flags as non-zero."""
    flags = (hb.motor_error_flag, hb.encoder_error_flag, hb.controller_error_flag)
    return [cmd for cmd, flag in zip(ERROR_REGISTERS, flags) if flag]


class AxisView:
    """The latest of everything node ``node_id`` sent, kept by :meth:`keep` (the receive thread), and the host's
    command state; ``cond`` guards it all (other parts of the driver guard their own state with it too)."""

    def __init__(self, node_id: int) -> None:
        self.node_id = node_id
        self.cond = threading.Condition()
        self.hb: cs.Heartbeat | None = None
        self.hb_ns: int | None = None  # when the newest heartbeat arrived (monotonic ns)
        # the latest heartbeats, (receive ns, heartbeat): a burst (a stalled host reading a full socket
        # buffer) must not hide the one a waiter looks for behind the ones after it
        self.hb_log: deque[tuple[int, cs.Heartbeat]] = deque(maxlen=HEARTBEAT_LOG)
        self.pos = math.nan
        self.vel = math.nan
        self.iq = math.nan
        self.vbus = math.nan
        self.ibus = math.nan
        self.telemetry_ns: int | None = None  # when the newest Encoder_Estimates arrived
        self.motor_error = 0
        self.encoder_error = 0
        self.controller_error = 0
        self.error_replies = dict.fromkeys(ERROR_REGISTERS, 0)  # answers received, per register
        self.rx_count = 0  # frames from this node
        self.parse_errors = 0  # frames on the bus that are not CAN Simple
        self.armed = False  # the host keeps the axis in closed loop (and feeds its watchdog)
        self.setpoint = 0.0  # the commanded velocity, turn/s

    def parse(self, frame: can.Message) -> cs.Message | None:
        """The message in ``frame`` if it came from this node (not a request), else None (a frame that is not CAN
        Simple is counted). Takes the lock only to count."""
        try:
            node, msg = cs.parse_message(frame)
        except cs.CanParseError:
            with self.cond:
                self.parse_errors += 1
            return None
        if node != self.node_id or isinstance(msg, cs.Request):
            return None
        return msg

    def keep(self, msg: cs.Message, host_ns: int) -> None:
        """Keep what ``msg`` (arrived at ``host_ns``) says; the caller holds :attr:`cond`."""
        self.rx_count += 1
        if isinstance(msg, cs.Heartbeat):
            self.hb, self.hb_ns = msg, host_ns
            self.hb_log.append((host_ns, msg))
            self.cond.notify_all()
        elif isinstance(msg, cs.EncoderEstimates):
            self.pos, self.vel = msg.pos, msg.vel
            self.telemetry_ns = host_ns
        elif isinstance(msg, cs.Iq):
            self.iq = msg.measured
        elif isinstance(msg, cs.BusVoltageCurrent):
            self.vbus, self.ibus = msg.voltage, msg.current
        elif isinstance(msg, cs.MotorError | cs.EncoderError | cs.ControllerErrorMsg):
            self._keep_register(msg)

    def _keep_register(self, msg: cs.MotorError | cs.EncoderError | cs.ControllerErrorMsg) -> None:
        if isinstance(msg, cs.MotorError):
            self.motor_error = msg.error
            self.error_replies[cs.Cmd.GET_MOTOR_ERROR] += 1
        elif isinstance(msg, cs.EncoderError):
            self.encoder_error = msg.error
            self.error_replies[cs.Cmd.GET_ENCODER_ERROR] += 1
        else:
            self.controller_error = msg.error
            self.error_replies[cs.Cmd.GET_CONTROLLER_ERROR] += 1
        self.cond.notify_all()

    def wait_heartbeat(
        self, pred: Callable[[cs.Heartbeat], bool], timeout_s: float, after_ns: int
    ) -> cs.Heartbeat | None:
        """First heartbeat received after ``after_ns`` satisfying ``pred`` (or None on timeout)."""
        with self.cond:
            return self.cond.wait_for(lambda: self._heartbeat_since(pred, after_ns), timeout_s) or None

    def _heartbeat_since(self, pred: Callable[[cs.Heartbeat], bool], after_ns: int) -> cs.Heartbeat | None:
        return next((hb for hb_ns, hb in self.hb_log if hb_ns > after_ns and pred(hb)), None)

    def wait_replies(self, before: dict[cs.Cmd, int], timeout_s: float) -> None:
        """Wait (at most ``timeout_s``) until every register in ``before`` (its answer count then) was answered."""
        with self.cond:
            self.cond.wait_for(lambda: all(self.error_replies[c] != n for c, n in before.items()), timeout_s)

    def fault_text(self, hb: cs.Heartbeat) -> str:
        """The fault a heartbeat reports, with the error registers' latest answers."""
        parts = [f"axis error {cs.error_names(hb.axis_error)}"]
        if hb.motor_error_flag or self.motor_error:
            parts.append(f"motor error {self.motor_error:#x}")
        if hb.encoder_error_flag or self.encoder_error:
            parts.append(f"encoder error {self.encoder_error:#x}")
        if hb.controller_error_flag or self.controller_error:
            parts.append(f"controller error {cs.error_names(self.controller_error, cs.ControllerError)}")
        state = AxisState(hb.axis_state).name if hb.axis_state in AxisState._value2member_map_ else hb.axis_state
        return f"ODrive node {self.node_id}: " + ", ".join(parts) + f" (state {state})"

    def latest(self) -> dict[str, float]:
        """Latest received values (NaN before the first) and the setpoint."""
        with self.cond:
            return {
                "position": self.pos,
                "velocity": self.vel,
                "iq_measured": self.iq,
                "bus_voltage": self.vbus,
                "bus_current": self.ibus,
                "setpoint": self.setpoint,
            }
