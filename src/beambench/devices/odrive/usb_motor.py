"""ODrive v3.6 (firmware 0.5.x) over USB through the ``odrive`` package (0.6.x), behind the ``Motor`` protocol.

Optional extra: ``pip install beambench[hardware]``; ``odrive`` is imported only when a device is opened.

**What is tested and what is not.** The ``odrive`` package reaches the board through libusb (its native
``libfibre``), which cannot run in this project's test environment (no device, no USB). The tests therefore
check only *our mapping logic* — limits → config properties, frequency → ``input_vel``, the watchdog and
idle sequence, telemetry and fault detection — against a plain in-process stand-in object that has the
firmware 0.5.x property tree (``axis0.controller.config.vel_limit`` …). The real USB path is untested here.

Property names follow the firmware 0.5.x interface (``odrive-interface.yaml``):

* limits: ``axis.controller.config.vel_limit`` (turn/s) = ``max_frequency_hz × 1.1``,
  ``axis.motor.config.current_lim`` (A) = ``max_current_a``, set before calibration and closed loop;
* mode: ``controller.config.control_mode = VELOCITY_CONTROL``, ``input_mode = VEL_RAMP``,
  ``vel_ramp_rate`` (turn/s²), ``controller.input_vel = 0``;
* watchdog: ``axis.config.watchdog_timeout``, ``watchdog_feed()``, then ``axis.config.enable_watchdog = True``;
  fed from the polling thread while armed; the previous ``enable_watchdog`` is restored by ``close()``;
* ``axis.requested_state`` / ``current_state``; errors from ``axis.error``, ``motor.error``,
  ``encoder.error``, ``controller.error``; ``odrv.clear_errors()``.

Telemetry rows are polled every ``poll_period_s`` (``encoder.pos_estimate``/``vel_estimate``,
``motor.current_control.Iq_measured``, ``vbus_voltage``, state and error). USB reads carry no device time:
``device_time`` is the host's monotonic clock at the read. There is no heartbeat on USB: a poll that has not
succeeded for ``heartbeat_timeout_s`` (300 ms) makes :meth:`OdriveUsbMotor.check` raise. Rows wait in a buffer
for the run's reads; a full buffer evicts its oldest row, and :meth:`OdriveUsbMotor.health` counts those as
``dropped`` (the run records them as lost, as it does every stream's).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

from beambench.acquisition.capabilities import DeviceFault, MotorLimits
from beambench.acquisition.streams import MOTOR
from beambench.devices.odrive.cansimple import (
    AxisError,
    AxisState,
    ControlMode,
    InputMode,
    error_names,
)
from beambench.devices.odrive.host_stall import HostStall, idle_not_confirmed
from beambench.devices.odrive.limits import LimitError, current_limit_for, vel_limit_for
from beambench.devices.odrive.telemetry import MAX_BUFFERED_ROWS, TelemetryStream


def find_odrive(serial_number: str | None = None, timeout_s: float = 10.0) -> Any:
    """The ``odrive`` package's device object (USB); DeviceFault if the extra is missing or none found."""
    try:
        import odrive
    except ImportError as exc:
        raise DeviceFault("the `odrive` package is not installed: pip install 'beambench[hardware]'") from exc
    try:
        return odrive.find_any(serial_number=serial_number, timeout=timeout_s)
    except TimeoutError as exc:
        raise DeviceFault(f"no ODrive found on USB within {timeout_s:g} s") from exc
    except Exception as exc:
        raise DeviceFault(f"cannot reach an ODrive on USB: {exc}") from exc


@dataclass(frozen=True)
class UsbMotorTiming:
    """How :class:`OdriveUsbMotor` finds, arms and watches the axis (seconds)."""

    find_timeout_s: float = 10.0
    calibrate: bool | None = None  # None: only if motor or encoder is not calibrated
    watchdog_timeout_s: float = 0.5  # the axis's own watchdog, fed by the poller
    poll_period_s: float = 0.02
    heartbeat_timeout_s: float = 0.3  # no successful poll this long: a fault
    closed_loop_timeout_s: float = 2.0
    calibration_timeout_s: float = 30.0
    idle_confirm_s: float = 0.5  # after idle(): how long to wait for the axis to report IDLE


class OdriveUsbMotor(TelemetryStream):
    """One axis of an ODrive v3.6 reached over USB. ``odrv`` may be given (an already-found device); ``timing``:
    how it finds, arms and watches the axis (:class:`UsbMotorTiming`)."""

    name = MOTOR

    def __init__(
        self,
        serial_number: str | None = None,
        axis: int = 0,
        *,
        odrv: Any = None,
        vel_ramp_rate: float = 20.0,
        timing: UsbMotorTiming = UsbMotorTiming(),
        max_buffered_rows: int = MAX_BUFFERED_ROWS,
    ) -> None:
        if axis not in (0, 1):
            raise ValueError(f"axis must be 0 or 1 (ODrive v3.6 has two), got {axis}")
        self.serial_number, self.axis_index = serial_number, axis
        self.timing = timing
        self.find_timeout_s = timing.find_timeout_s
        self.calibrate = timing.calibrate
        self.vel_ramp_rate = vel_ramp_rate
        self.watchdog_timeout_s = timing.watchdog_timeout_s
        self.poll_period_s = timing.poll_period_s
        self.heartbeat_timeout_s = timing.heartbeat_timeout_s
        self.closed_loop_timeout_s = timing.closed_loop_timeout_s
        self.calibration_timeout_s = timing.calibration_timeout_s
        self._odrv = odrv
        self._ax: Any = None
        self._lock = threading.Lock()
        self._guard = self._lock
        self._rows: deque[tuple] = deque(maxlen=max_buffered_rows)  # a full one evicts its oldest row, counted
        self.rows_received = self.rows_evicted = 0  # TelemetryStream._buffer counts them
        self._streaming = False
        self._armed = False
        self._limits: MotorLimits | None = None
        self._setpoint = 0.0
        self._last_ok_ns: int | None = None
        self._state = int(AxisState.UNDEFINED)
        self._error = 0
        self._sub_errors: dict[str, int] = {}
        self._link_error: str | None = None
        self._stall = HostStall()  # the host's own stall (no CPU time), not the link's silence
        self._saved_watchdog: bool | None = None
        self._poller: threading.Thread | None = None
        self._stop = threading.Event()
        self._closed = False
        self.vel_limit: float | None = None
        self.current_limit: float | None = None
        self.idle_errors: list[str] = []

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> None:
        if self._ax is not None:
            return
        if self._closed:
            raise DeviceFault("OdriveUsbMotor is closed")
        if self._odrv is None:
            self._odrv = find_odrive(self.serial_number, self.find_timeout_s)
        self._ax = getattr(self._odrv, f"axis{self.axis_index}")
        self._last_ok_ns = time.monotonic_ns()
        self._stop.clear()
        self._poller = threading.Thread(target=self._poll_loop, name="odrive-usb", daemon=True)
        self._poller.start()

    def close(self) -> None:
        """Idle, stop polling, restore the previous ``enable_watchdog``. Idempotent, never raises."""
        if self._closed:
            return
        self.idle()
        self._stop.set()
        if self._poller is not None:
            self._poller.join(timeout=1.0)
            self._poller = None
        if self._ax is not None and self._saved_watchdog is not None:
            try:
                self._ax.config.enable_watchdog = self._saved_watchdog
            except Exception as exc:
                self.idle_errors.append(f"restore enable_watchdog: {exc}")
        self._closed = True

    def __enter__(self) -> OdriveUsbMotor:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ polling thread
    def _poll_once(self) -> None:
        ax, odrv = self._ax, self._odrv
        with self._lock:
            armed, setpoint = self._armed, self._setpoint
        if armed:
            ax.watchdog_feed()
        pos = float(ax.encoder.pos_estimate)
        vel = float(ax.encoder.vel_estimate)
        iq = float(ax.motor.current_control.Iq_measured)
        vbus = float(odrv.vbus_voltage)
        state = int(ax.current_state)
        error = int(ax.error)
        sub = {}
        if error:
            sub = {
                "motor": int(ax.motor.error),
                "encoder": int(ax.encoder.error),
                "controller": int(ax.controller.error),
            }
        now = time.monotonic_ns()
        with self._lock:
            self._last_ok_ns = now
            self._link_error = None
            self._state, self._error, self._sub_errors = state, error, sub
            if self._streaming:
                self._buffer((now, now * 1e-9, pos, vel, setpoint, iq, vbus, state, error))

    def _poll_loop(self) -> None:
        while not self._stop.wait(self.poll_period_s):
            self._note_stall(time.monotonic_ns())
            try:
                self._poll_once()
            except Exception as exc:
                with self._lock:
                    self._link_error = f"{type(exc).__name__}: {exc}"

    def _note_stall(self, now_ns: int) -> None:
        """A wake-up of this process's (the poller's, or a check's): a stall since the last one is recorded."""
        with self._lock:
            self._stall.note(now_ns, self._armed, self.heartbeat_timeout_s, self.watchdog_timeout_s)
            self._stall.tick(now_ns)

    # ------------------------------------------------------------------ Motor protocol (stream: TelemetryStream)
    def arm(self, limits: MotorLimits) -> None:
        vel_limit = vel_limit_for(limits)
        current = current_limit_for(limits)
        self.open()
        ax = self._ax
        try:
            self._odrv.clear_errors()
            ax.controller.config.vel_limit = vel_limit
            ax.motor.config.current_lim = current
            self.vel_limit, self.current_limit = vel_limit, current
            ax.controller.config.control_mode = int(ControlMode.VELOCITY_CONTROL)
            ax.controller.config.input_mode = int(InputMode.VEL_RAMP)
            ax.controller.config.vel_ramp_rate = float(self.vel_ramp_rate)
            ax.controller.input_vel = 0.0
            if self._saved_watchdog is None:
                self._saved_watchdog = bool(ax.config.enable_watchdog)
            ax.config.watchdog_timeout = float(self.watchdog_timeout_s)
            ax.watchdog_feed()
            ax.config.enable_watchdog = True
            with self._lock:
                self._limits, self._setpoint = limits, 0.0
                self._stall.stall_ns = 0
            needs_cal = self.calibrate
            if needs_cal is None:
                needs_cal = not (bool(ax.motor.is_calibrated) and bool(ax.encoder.is_ready))
            if needs_cal:
                ax.requested_state = int(AxisState.FULL_CALIBRATION_SEQUENCE)
                self._wait_state(lambda s: s != AxisState.IDLE, 1.0, "start calibrating", feed=True, allow_fast=True)
                self._wait_state(
                    lambda s: s == AxisState.IDLE, self.calibration_timeout_s, "finish calibration", feed=True
                )
                self._raise_errors("calibration failed")
            with self._lock:
                self._armed = True
            ax.watchdog_feed()
            ax.requested_state = int(AxisState.CLOSED_LOOP_CONTROL)
            self._wait_state(
                lambda s: s == AxisState.CLOSED_LOOP_CONTROL, self.closed_loop_timeout_s, "enter closed loop", feed=True
            )
        except DeviceFault:
            self.idle()
            raise
        except Exception as exc:
            self.idle()
            raise DeviceFault(f"ODrive USB arm failed: {type(exc).__name__}: {exc}") from exc

    def _wait_state(self, pred, timeout_s: float, what: str, feed: bool, allow_fast: bool = False) -> None:
        ax = self._ax
        end = time.monotonic() + timeout_s
        while True:
            if feed:
                ax.watchdog_feed()
            state = int(ax.current_state)
            if pred(state):
                return
            if int(ax.error):
                self._raise_errors(f"failed to {what}")
            if time.monotonic() >= end:
                if allow_fast and state == AxisState.IDLE:
                    return  # finished before we looked (instant on a pre-calibrated axis)
                raise DeviceFault(f"ODrive axis{self.axis_index} did not {what} within {timeout_s:g} s (state {state})")
            time.sleep(min(0.01, self.poll_period_s))

    def _raise_errors(self, context: str) -> None:
        ax = self._ax
        err = int(ax.error)
        if err:
            raise DeviceFault(
                f"{context}: axis error {error_names(err)}, motor error {int(ax.motor.error):#x}, "
                f"encoder error {int(ax.encoder.error):#x}, controller error {int(ax.controller.error):#x}"
            )

    def set_frequency(self, hz: float) -> None:
        if not math.isfinite(hz):
            raise LimitError(f"frequency {hz!r} is not a number")
        limits = self._limits
        if limits is None or not self._armed:
            raise DeviceFault("set_frequency() before arm()")
        if abs(hz) > limits.max_frequency_hz:
            raise LimitError(f"frequency {hz:g} Hz exceeds limits.max_frequency_hz = {limits.max_frequency_hz:g}")
        with self._lock:
            self._setpoint = float(hz)
        self._ax.controller.input_vel = float(hz)

    def idle(self) -> None:
        """``input_vel = 0`` and ``requested_state = IDLE``. Idempotent; never raises."""
        with self._lock:
            self._armed = False
            self._setpoint = 0.0
        if self._ax is None or self._closed:
            return
        for step in ("state", "input_vel"):
            try:
                if step == "state":
                    self._ax.requested_state = int(AxisState.IDLE)
                else:
                    self._ax.controller.input_vel = 0.0
            except Exception as exc:
                self.idle_errors.append(f"idle {step}: {exc}")

    def confirm_idle(self) -> str:
        """After :meth:`idle`: "motor idle" once the axis reports AXIS_STATE_IDLE (waiting at most
        ``timing.idle_confirm_s``); otherwise "idle NOT confirmed" and when the ODrive's watchdog idles it."""
        end = time.monotonic() + self.timing.idle_confirm_s
        while self._ax is not None and not self._closed:
            try:
                if int(self._ax.current_state) == AxisState.IDLE:
                    return f"motor idle (ODrive axis{self.axis_index} confirms AXIS_STATE_IDLE over USB)"
            except Exception as exc:  # the link is gone: nothing to confirm with
                self.idle_errors.append(f"confirm idle: {exc}")
                break
            if time.monotonic() >= end:
                break
            time.sleep(min(0.01, self.poll_period_s))
        return idle_not_confirmed(self.watchdog_timeout_s)

    def check(self) -> None:
        self._note_stall(time.monotonic_ns())
        with self._lock:
            if self._last_ok_ns is None:
                return
            if self._stall.stall_ns and self._armed:  # whatever the ODrive says now follows from the host's stall
                raise DeviceFault(self._stall.text(f"ODrive axis{self.axis_index} over USB", self.watchdog_timeout_s))
            age_s = (time.monotonic_ns() - self._last_ok_ns) * 1e-9
            if age_s > self.heartbeat_timeout_s:
                why = f" ({self._link_error})" if self._link_error else ""
                raise DeviceFault(
                    f"ODrive USB link lost for {age_s * 1e3:.0f} ms (> {self.heartbeat_timeout_s * 1e3:.0f} ms){why}"
                )
            if self._error:
                sub = ", ".join(f"{k} error {v:#x}" for k, v in self._sub_errors.items() if v)
                raise DeviceFault(
                    f"ODrive axis{self.axis_index}: axis error {error_names(self._error)}" + (f", {sub}" if sub else "")
                )
            if self._armed and self._state != AxisState.CLOSED_LOOP_CONTROL:
                raise DeviceFault(f"ODrive axis{self.axis_index} left closed loop (state {self._state})")

    def health(self) -> dict[str, Any]:
        """Counters for the session (``ReportsHealth``, as the CAN driver's): telemetry rows polled while streaming
        (``received``), rows a full buffer evicted before anyone read them (``dropped``: the run says them lost),
        rows polled but never read (``unrecorded``), and the last USB error (``link_error``)."""
        with self._lock:
            return {
                "received": self.rows_received,
                "dropped": self.rows_evicted,
                "unrecorded": len(self._rows),
                "link_error": self._link_error or "",
            }

    def identity(self) -> dict[str, Any]:
        info: dict[str, Any] = {
            "driver": "beambench.devices.odrive.usb_motor.OdriveUsbMotor",
            "axis": self.axis_index,
            "vel_limit_turn_s": self.vel_limit,
            "current_limit_a": self.current_limit,
        }
        if self._odrv is not None:
            info.update(_device_info(self._odrv))
        return info


def _device_info(odrv: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    try:
        out["serial_number"] = f"{int(odrv.serial_number):012X}"
        out["firmware"] = f"{odrv.fw_version_major}.{odrv.fw_version_minor}.{odrv.fw_version_revision}"
        out["hardware"] = f"v{odrv.hw_version_major}.{odrv.hw_version_minor}-{odrv.hw_version_variant}V"
        out["bus_voltage_v"] = round(float(odrv.vbus_voltage), 3)
    except Exception as exc:
        out["error"] = str(exc)
    return out


def ping(serial_number: str | None = None, timeout_s: float = 3.0, *, odrv: Any = None) -> dict[str, Any]:
    """Find an ODrive on USB and report serial, firmware, hardware, bus voltage and axis states.

    Never moves anything and never raises: ``found`` is False with an ``error`` when nothing answers.
    """
    info: dict[str, Any] = {"device": "ODrive v3.6 (USB)", "found": False}
    try:
        dev = odrv if odrv is not None else find_odrive(serial_number, timeout_s)
    except DeviceFault as exc:
        info["error"] = str(exc)
        return info
    info["found"] = True
    info.update(_device_info(dev))
    for i in (0, 1):
        try:
            ax = getattr(dev, f"axis{i}")
            info[f"axis{i}"] = {
                "state": AxisState(int(ax.current_state)).name,
                "error": error_names(int(ax.error), AxisError),
            }
        except Exception:
            pass
    return info
