"""Closed-loop walking speed: feed-forward from a speed map, feedback from the mocap body speed (backend-free).

Each control tick (``control.control_s`` of rig time) :meth:`TrackController.update` decides the drive frequency:

- **band**: the map's band that reaches the target (:mod:`beambench.acquisition.control.speed_map`), kept while it does;
  a target of the other sign switches band (and resets the integrator). A target of 0 stands the walker at a
  frequency whose speed is ~0: the zero crossing of the map's run through zero that holds the band in use (the
  walker keeps stepping in place; feedback holds it there); from rest (no band yet) it stands at 0 Hz (the motor
  holds the crank still).
- **feed-forward**: the band's frequency whose measured speed is the target.
- **step** (a new segment): the walker's body takes a second or more to follow its drive (the sim walker's
  momentum), and how fast it gets there is not the map's to say (driven back from a forward walk the sim walker
  reaches ~-27 mm/s at 22 Hz where its ascending sweep measured -84), so a step is steered by the measured speed
  alone: the drive is set at once (the motor's own velocity ramp is the only limit) to the map's frequency for
  ``target + lead × (target − v0)``, ``v0`` the speed measured at the step, past the target, so the body gets
  there sooner. That speed may lie beyond the band's zero edge, in the map's run through zero that holds the
  band: a slow-down brakes with backward speeds. The drive is held there until the measured speed, carried on at
  its measured acceleration for the time the motor needs to ramp back to the target's frequency (at
  ``rate_hz_s``; the body keeps being pushed meanwhile) plus half the speed window (its lag), reaches the target,
  or the measured speed is within :data:`HANDOVER_MM_S` of it, or after 4 ``body_tau_s``; the frequency then
  goes straight to the feedback's. A stop (target 0) from a walk leads to 0 Hz instead: the crank held still,
  the feet planted, the sim walker's body brakes at ~600 mm/s², where its backward gait brakes it at ~140 mm/s²
  at most; it then stands in place (below). The planted legs give some of the body's speed back: if it swings
  back past 0 by more than :data:`REBOUND_MM_S`, one more step from there (in the run through zero, crank turning).
  Stopping the motor for the whole segment would not do: once stopped the body rocks on its legs at up to
  ±25 mm/s for more than a second (docs/walker-twin.md). With ``feedback: false`` there is no step (nothing is
  measured): the map's frequency, rate limited.
- **feedback** (PI, in speed units): ``u = target + kp·e + I`` with ``e = target − measured``, then the band's
  frequency for ``u``. Working in speed and inverting through the map keeps the loop gain near ``kp`` however
  steep the map is locally. ``u`` is clipped to the band's speeds (its frequency edges); the integrator does not
  grow while clipped, while the rate limit holds the frequency back, or while the error is a transient's (larger
  than ``integrate_within`` × |target| + 10 mm/s): anti-windup. The integrator is kept from segment to segment
  within a band (a map off by a steady amount stays corrected) and reset when the band changes.
- **rate limit**: the feedback's corrections move the commanded frequency by at most ``rate_hz_s`` per second.
- **measured speed**: least-squares slope of the body marker along the forward axis over the last
  ``window_periods`` drive periods (within ``min_window_s``..``max_window_s``), against the mocap's own timestamps.
- **mocap lost** (no body sample for a tick): the frequency is held and the integrator frozen; after
  ``mocap_lost_s`` without data the walker stands (0 Hz) until the body is seen again.

Every decision is a row of the ``track`` stream (:func:`track_spec`), which the hub hands to the session file and
the live view like any other stream. The controller is itself a hub sink: it reads the mocap batches going by.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from beambench.acquisition.batch import Batch, ColumnSpec, StreamSpec
from beambench.acquisition.control.speed_map import Band, SpeedMap
from beambench.acquisition.protocol.schema import TrackControl
from beambench.acquisition.streams import MOCAP, MOTOR

TRACK = "track"
INTEGRATE_ABS_MM_S = 10.0  # the integrator's error band: control.integrate_within × |target| + this
ACCEL_LAG_S = 0.1  # the measured acceleration: the windowed speed now against this long before
HANDOVER_MM_S = 5.0  # a step ends when the measured speed is this close to the target (then PI)
REBOUND_MM_S = 10.0  # a stop's catch: the body swinging back past 0 by more than this takes one more step
MOTOR_FRESH_S = 0.2  # motor telemetry older than this is not used (then the motor is taken to ramp at rate_hz_s)

# modes (the ``mode`` column)
TRACKING, HOLDING, STANDING, LOST = 0, 1, 2, 3
MODES = {TRACKING: "tracking", HOLDING: "mocap lost: holding", STANDING: "standing", LOST: "mocap lost: standing"}


def track_spec(control_s: float) -> StreamSpec:
    """The controller's decisions, one row per control tick."""
    f = "float64"
    return StreamSpec(
        TRACK,
        1.0 / control_s,
        {
            "target_mm_s": ColumnSpec((), f, "mm/s", (), "target speed along the forward axis", plotted=True),
            "measured_mm_s": ColumnSpec((), f, "mm/s", (), "windowed body speed (NaN: none)", plotted=True),
            "feedforward_hz": ColumnSpec((), f, "Hz", (), "the map's frequency for the target", plotted=True),
            "frequency_hz": ColumnSpec((), f, "Hz", (), "commanded drive frequency", plotted=True),
            "integral_mm_s": ColumnSpec((), f, "mm/s", (), "feedback integrator"),
            "band": ColumnSpec((), "int32", "", (), "band index in the map (-1: none, standing)"),
            "mode": ColumnSpec((), "int32", "", (), "0 tracking, 1 mocap lost (holding), 2 standing, 3 lost (stand)"),
            "segment": ColumnSpec((), "int32", "", (), "profile segment"),
        },
        description="speed controller decisions",
    )


def _axis(name: str) -> np.ndarray:
    v = np.zeros(3)
    v["xyz".index(name.lstrip("+-"))] = -1.0 if name.startswith("-") else 1.0
    return v


class SpeedEstimator:
    """The body's forward position as it arrives; :meth:`speed` fits the slope over a recent window.

    Samples are chosen by host receive time (what "recent" means to the controller) and fitted against the mocap's
    own timestamps (``device_time``: exposure times at a steady 360 Hz), so receive jitter on a busy host or network
    does not enter the speed."""

    def __init__(self, keep_s: float) -> None:
        self.keep_ns = int(keep_s * 1e9)
        self._t: deque[int] = deque()
        self._d: deque[float] = deque()
        self._x: deque[float] = deque()

    def add(self, t_ns: np.ndarray, x_m: np.ndarray, device_s: np.ndarray | None = None) -> None:
        dev = (t_ns * 1e-9) if device_s is None else device_s
        for t, d, x in zip(t_ns.tolist(), np.asarray(dev, float).tolist(), x_m.tolist()):
            if math.isfinite(x) and math.isfinite(d) and (not self._t or t >= self._t[-1]):
                self._t.append(int(t))
                self._d.append(float(d))
                self._x.append(float(x))
        while self._t and self._t[-1] - self._t[0] > self.keep_ns:
            self._t.popleft()
            self._d.popleft()
            self._x.popleft()

    @property
    def last_ns(self) -> int | None:
        return self._t[-1] if self._t else None

    def speed(self, now_ns: int, window_s: float) -> float:
        """Slope (mm/s) over the samples received in the last ``window_s`` before ``now_ns``; NaN if their
        timestamps cover less than 80 % of it."""
        if not self._t:
            return math.nan
        t = np.asarray(self._t, np.int64)
        k = t >= now_ns - int(window_s * 1e9)
        d = np.asarray(self._d)[k]
        if k.sum() < 3 or np.ptp(d) < 0.8 * window_s:
            return math.nan
        xs = np.asarray(self._x)[k] * 1e3
        dc = d - d.mean()
        return float(dc @ (xs - xs.mean()) / (dc @ dc))


@dataclass
class Decision:
    """One control tick's outcome (a row of the ``track`` stream)."""

    t_ns: int
    target_mm_s: float
    measured_mm_s: float
    feedforward_hz: float
    frequency_hz: float
    integral_mm_s: float
    band: int
    mode: int
    segment: int


class TrackController:
    """Speed → frequency, every tick (see the module docstring); a hub sink that reads the mocap's body marker."""

    name = "track_controller"

    def __init__(
        self, speed_map: SpeedMap, control: TrackControl, max_frequency_hz: float, mocap_lost_s: float, body: str
    ) -> None:
        """``body``: the marker whose speed is tracked (the walking scene's ``SceneInfo.body_marker``)."""
        self.map, self.c, self.body_marker = speed_map, control, body
        self.max_hz = max_frequency_hz
        self.lost_ns = int(mocap_lost_s * 1e9)
        self.est = SpeedEstimator(control.max_window_s + 0.5)
        self._body: int | None = None
        self._fwd = _axis("x")
        self.target = 0.0
        self.segment = -1
        self.band: Band | None = None
        self.integral = 0.0
        self.f_cmd = 0.0
        self._last_tick_ns: int | None = None
        self._lost_since: int | None = None
        self._motor: tuple[int, float] | None = None  # (host time ns, measured |velocity| Hz) of the last motor row
        self._pending = False  # a new segment: its step starts at the next tick
        self._leading = False  # a step in progress: the drive held past the target until the body will get there
        self._stepped_at = 0  # when the step started (ns)
        self._step_sign = 1.0  # the step's direction: +1 speeding up (forward), -1 slowing down
        self._step_from = 0.0  # the speed measured at the step's start (mm/s)
        self._catch = False  # the step is a stop's: the crank held still (0 Hz)
        self._rebound = False  # a stop's catch ended: one more step if the body swings back past the target
        self._f_motor = 0.0  # the motor's frequency: its telemetry, else a ramp at rate_hz_s toward the command

    # --- sink -----------------------------------------------------------------------------------------
    def open(self, specs: list[StreamSpec]) -> None:
        mocap = next((s for s in specs if s.name == MOCAP), None)
        if mocap is None:
            raise ValueError("speed tracking needs a mocap stream")
        labels = mocap.columns["data"].labels
        if self.body_marker not in labels:
            raise ValueError(f"speed tracking needs a {self.body_marker!r} marker (mocap has {', '.join(labels)})")
        self._body = labels.index(self.body_marker)
        if mocap.frame is not None:
            self._fwd = _axis(mocap.frame.forward_axis)

    def write(self, batch: Batch) -> None:
        if batch.stream == MOTOR and len(batch) and "velocity" in batch.columns:
            v = float(np.asarray(batch.columns["velocity"], float)[-1])
            if math.isfinite(v):
                self._motor = (int(batch.host_time_ns[-1]), abs(v))
            return
        if batch.stream != MOCAP or not len(batch) or self._body is None:
            return
        pos = np.asarray(batch.columns["data"], float)[:, self._body]
        x = pos @ self._fwd
        occ = batch.columns.get("occluded")
        if occ is not None:
            x = np.where(np.asarray(occ)[:, self._body], np.nan, x)
        self.est.add(np.asarray(batch.host_time_ns, np.int64), x, np.asarray(batch.device_time, float))

    def event(self, host_time_ns: int, kind: str, message: str) -> None:
        pass

    def close(self) -> None:
        pass

    # --- control --------------------------------------------------------------------------------------
    def set_target(self, speed_mm_s: float, segment: int) -> float:
        """A new segment: choose its band (a sign change switches band and resets the integrator); returns the
        feed-forward frequency (0 to stand)."""
        if speed_mm_s == 0:
            band = self.map.stand_band(self.band, self.max_hz)
        else:
            band = self.map.band_for(speed_mm_s, self.max_hz, self.band)
        if band is None and speed_mm_s != 0:
            raise ValueError(f"target {speed_mm_s:g} mm/s: out of reach of the speed map")
        if band is None or self.band is None or band.index != self.band.index:
            self.integral = 0.0
        self.band, self.target, self.segment = band, float(speed_mm_s), segment
        self._pending = True
        return self.feedforward()

    @property
    def stepping(self) -> bool:
        """A new segment's step is under way (its next tick, or its lead): the frequency may jump."""
        return self._pending or self._leading

    def feedforward(self) -> float:
        return 0.0 if self.band is None else min(self.band.frequency_for(self.target), self.max_hz)

    def _motor_frequency(self, now_ns: int, dt: float) -> float:
        """The motor's drive frequency: its telemetry when fresh, else a ramp at ``rate_hz_s`` toward the command."""
        motor = self._motor
        if motor is not None and now_ns - motor[0] <= MOTOR_FRESH_S * 1e9:
            self._f_motor = motor[1]
        else:
            step = self.c.rate_hz_s * dt
            self._f_motor = min(max(self.f_cmd, self._f_motor - step), self._f_motor + step)
        return self._f_motor

    def _accel(self, now_ns: int, measured: float) -> float:
        """The body's measured acceleration (mm/s²): the windowed speed now against ``ACCEL_LAG_S`` earlier."""
        before = self.est.speed(now_ns - int(ACCEL_LAG_S * 1e9), self.window_s())
        if not (math.isfinite(measured) and math.isfinite(before)):
            return 0.0
        return (measured - before) / ACCEL_LAG_S

    def _step_frequency(self, now_ns: int, dt: float, measured: float) -> float | None:
        """During a step: the lead's frequency, in the run through zero speed that holds the band (None: the step is
        over, see the module docstring)."""
        band = self.band
        assert band is not None
        run = self.map.stand_band(band, self.max_hz) or band
        f_motor, ff = self._f_motor, self.feedforward()
        if self._catch:  # a stop: the crank held still brakes the body hardest (see the module docstring)
            f_lead = 0.0
        else:
            f_lead = min(run.frequency_for(self.target + self.c.lead * (self.target - self._step_from)), self.max_hz)
        passed = (f_motor - ff) * (f_lead - ff) >= 0  # the motor got to the target's frequency on its way to the lead's
        if math.isfinite(measured) and passed:
            back_s = abs(f_motor - ff) / self.c.rate_hz_s
            ahead = measured + self._accel(now_ns, measured) * (back_s + 0.5 * self.window_s())
            if abs(self.target - measured) <= HANDOVER_MM_S or (self.target - ahead) * self._step_sign <= 0:
                self._leading = False
                return None
        if now_ns - self._stepped_at > 4 * self.c.body_tau_s * 1e9:
            self._leading = False
            return None
        return f_lead

    def _start_step(self, now_ns: int, speed: float, catch: bool) -> None:
        """A step from the measured ``speed`` (see the module docstring); ``catch``: a stop's, the crank held still."""
        self._pending, self._stepped_at = False, now_ns
        self._leading = self.band is not None and self.c.feedback  # feed-forward alone measures nothing
        self._step_sign = 1.0 if self.target >= speed else -1.0
        self._step_from = speed
        self._catch = self._rebound = catch and self._leading

    def window_s(self) -> float:
        """The speed window: ``window_periods`` drive periods, clipped; a crank held still (0 Hz) has no period to
        average over, so the shortest (the lag of a long window would hide a stop's quick braking)."""
        if self.f_cmd <= 0:
            return self.c.min_window_s
        return min(max(self.c.window_periods / self.f_cmd, self.c.min_window_s), self.c.max_window_s)

    def update(self, now_ns: int) -> Decision:
        """One tick at rig time ``now_ns``: the next commanded frequency (also in :attr:`f_cmd`)."""
        dt = self.c.control_s if self._last_tick_ns is None else max((now_ns - self._last_tick_ns) * 1e-9, 0.0)
        self._last_tick_ns = now_ns
        ff = self.feedforward()
        measured = self.est.speed(now_ns, self.window_s())
        last = self.est.last_ns
        fresh = last is not None and now_ns - last <= max(int(2 * self.c.control_s * 1e9), int(0.05e9))
        if fresh:
            self._lost_since = None
        elif self._lost_since is None:
            self._lost_since = last if last is not None else now_ns
        lost_for = 0 if self._lost_since is None else now_ns - self._lost_since
        if not fresh and lost_for > self.lost_ns:
            self.f_cmd, mode = 0.0, LOST  # stand: never drive blind
        elif not fresh:
            mode = HOLDING  # hold the last frequency, the integrator frozen
        else:
            mode = STANDING if self.band is None else TRACKING
            f_motor = self._motor_frequency(now_ns, dt)
            if self._pending:  # a new segment: its step (the motor's own ramp is the only limit)
                now_speed = measured if math.isfinite(measured) else self.map.speed_at(f_motor)
                self._start_step(now_ns, now_speed, catch=self.target == 0)
            elif self._rebound and not self._leading and (self.target - measured) * self._step_sign < -REBOUND_MM_S:
                self._start_step(now_ns, measured, catch=False)  # a stop's catch swung the body back past 0
            leading = self._leading
            lead = self._step_frequency(now_ns, dt, measured) if leading else None
            if self.band is None:
                self.f_cmd = 0.0
            elif lead is not None:
                self.f_cmd = lead
            elif leading:  # the step is over: straight back from the lead's overdrive to the feedback's frequency
                self.f_cmd = self._desired(measured, dt)
            else:
                self.f_cmd = self._rate_limited(self._desired(measured, dt), dt)
        band = -1 if self.band is None else self.band.index
        return Decision(now_ns, self.target, measured, ff, self.f_cmd, self.integral, band, mode, self.segment)

    def _desired(self, measured: float, dt: float) -> float:
        band = self.band
        assert band is not None
        if not self.c.feedback or not math.isfinite(measured):
            return min(band.frequency_for(self.target + self.integral), self.max_hz)
        e = self.target - measured
        u = self.target + self.c.kp * e + self.integral
        clipped = band.clip(u)
        f_des = min(band.frequency_for(clipped), self.max_hz)
        held_back = abs(f_des - self.f_cmd) > self.c.rate_hz_s * dt + 1e-9
        saturated = (u > clipped and e > 0) or (u < clipped and e < 0) or (f_des >= self.max_hz and e * band.sign > 0)
        transient = abs(e) > self.c.integrate_within * abs(self.target) + INTEGRATE_ABS_MM_S
        if not (saturated or held_back or transient):
            self.integral += self.c.ki_per_s * e * dt
            self.integral = band.clip(self.target + self.integral) - self.target  # never beyond the band
        return f_des

    def _rate_limited(self, f_des: float, dt: float) -> float:
        step = self.c.rate_hz_s * dt
        return float(min(max(f_des, self.f_cmd - step), self.f_cmd + step, self.max_hz))


def decisions_batch(rows: list[Decision]) -> Batch:
    """Rows of the ``track`` stream as one batch (device time = host time, s: the controller runs on the host)."""
    t = np.array([r.t_ns for r in rows], np.int64)
    col = {
        name: np.array([getattr(r, name) for r in rows], np.float64)
        for name in ("target_mm_s", "measured_mm_s", "feedforward_hz", "frequency_hz", "integral_mm_s")
    }
    col.update({name: np.array([getattr(r, name) for r in rows], np.int32) for name in ("band", "mode", "segment")})
    return Batch(TRACK, t, t * 1e-9, col)
