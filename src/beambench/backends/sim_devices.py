"""Simulated devices with the same streams as the real ones, sampled from the physics trajectory.

Every device samples on its own clock (:class:`~beambench.acquisition.clocks.DriftingClock`: device time
D(t) = offset + (1 + drift)·t), samples at D = k/rate.
A sample measured at true time t reaches the host at t + latency + jitter (one-sided, exponential with mean
``jitter_s``; first in, first out, so host times strictly increase). Host time is the simulated time since
``open()``. A device delivers every sample measured at or before the clock's "now"; a sample's host time may
lie up to latency + jitter after "now" (it is in flight when the run reads it).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from beambench.acquisition.batch import Batch, StreamSpec
from beambench.acquisition.capabilities import DeviceFault, MotorLimits
from beambench.acquisition.clocks import DriftingClock
from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration
from beambench.acquisition.protocol.schema import ClockModel
from beambench.acquisition.streams import loadcell_spec, mocap_spec, motor_spec

if TYPE_CHECKING:  # the simulated devices read the trajectory's arrays: no MuJoCo needed to import them
    from beambench.sim.engine.stepping import Trajectory
    from beambench.sim.scenes.drive import VelocityRamp

# ODrive enums (odrive.enums, firmware 0.5/0.6)
AXIS_STATE_IDLE = 1
AXIS_STATE_CLOSED_LOOP_CONTROL = 8
ERROR_CURRENT_LIMIT_VIOLATION = 0x1000  # ODriveError.CURRENT_LIMIT_VIOLATION (0.6)


# --- interpolation helpers ---------------------------------------------------------------------------
def interp_rows(t: np.ndarray, y: np.ndarray, tq: np.ndarray) -> np.ndarray:
    """Linear interpolation of rows ``y[n, ...]`` at times ``tq`` (clamped at the ends)."""
    i = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, len(t) - 2)
    dt = t[i + 1] - t[i]
    w = np.clip((tq - t[i]) / np.where(dt > 0, dt, 1.0), 0.0, 1.0)
    w = w.reshape(w.shape + (1,) * (y.ndim - 1))
    return y[i] * (1 - w) + y[i + 1] * w


def box_average(t: np.ndarray, y: np.ndarray, tq: np.ndarray, width: float) -> np.ndarray:
    """Mean of ``y`` over ``[tq - width, tq]`` (trapezoidal integral; what an ADC with a 1-sample boxcar reads)."""
    seg = 0.5 * (y[1:] + y[:-1]) * np.diff(t).reshape(-1, *([1] * (y.ndim - 1)))
    cum = np.concatenate([np.zeros((1, *y.shape[1:])), np.cumsum(seg, axis=0)])
    return (interp_rows(t, cum, tq) - interp_rows(t, cum, tq - width)) / width


# --- clocks ------------------------------------------------------------------------------------------
class DeviceClock:
    """A device's clock (offset, drift) and its link to the host (latency, jitter)."""

    def __init__(self, model: ClockModel, rate_hz: float, rng: np.random.Generator) -> None:
        self.model, self.rate, self.rng = model, rate_hz, rng
        self.drift = DriftingClock.from_model(model)
        self.scale = self.drift.scale
        self.k0 = math.ceil(self.device_time(0.0) * rate_hz - 1e-9)  # first sample after open()
        self._last_host_ns = -1

    def device_time(self, t: float | np.ndarray) -> float | np.ndarray:
        return self.drift.device_time(t)

    def true_time(self, d: float | np.ndarray) -> float | np.ndarray:
        return self.drift.true_time(d)

    def last_index(self, t: float) -> int:
        """Index of the last sample measured at or before true time ``t``."""
        return math.floor(self.device_time(t) * self.rate + 1e-9)

    def host_ns(self, t_true: np.ndarray) -> np.ndarray:
        delay = self.model.latency_s + (
            self.rng.exponential(self.model.jitter_s, len(t_true)) if self.model.jitter_s > 0 else 0.0
        )
        ns = np.round((t_true + delay) * 1e9).astype(np.int64)
        # FIFO link, strictly increasing: y_i strictly increasing <=> y_i - i non-decreasing
        i = np.arange(len(ns))
        ns = np.maximum.accumulate(np.maximum(ns - i, self._last_host_ns + 1)) + i
        if len(ns):
            self._last_host_ns = int(ns[-1])
        return ns


class SimClock:
    """The rig clock: ``wait`` advances the physics; with ``realtime`` it also paces to the wall clock."""

    def __init__(self, advance: Callable[[int], None], realtime: bool = False, max_chunk_s: float = 0.5) -> None:
        self._advance = advance
        self.realtime = realtime
        self.max_chunk_s = max_chunk_s
        self._now_ns = 0
        self._wall0 = time.monotonic()

    def reset(self) -> None:
        self._now_ns = 0
        self._wall0 = time.monotonic()

    def now_ns(self) -> int:
        return self._now_ns

    def wait(self, seconds: float) -> None:
        if seconds <= 0:
            return
        target = self._now_ns + round(seconds * 1e9)
        step = int(self.max_chunk_s * 1e9)
        while self._now_ns < target:
            self._now_ns = min(target, self._now_ns + step)
            self._advance(self._now_ns)
            if self.realtime:
                lag = self._now_ns * 1e-9 - (time.monotonic() - self._wall0)
                if lag > 0:
                    time.sleep(lag)


# --- streams -----------------------------------------------------------------------------------------
class SampledStream:
    """A stream sampled from the trajectory on its own device clock; ``read`` drains what has arrived.
    A subclass implements :meth:`sample` and says what it simulates in ``kind`` (and :meth:`about`)."""

    kind = ""  # what it simulates, for the session's device identities

    def __init__(self, spec: StreamSpec, clock: DeviceClock) -> None:
        self.name = spec.name
        self.spec = spec
        self.clock = clock
        self.next_k = clock.k0
        self.running = False
        self._pending: list[Batch] = []

    def describe(self) -> StreamSpec:
        return self.spec

    def start(self) -> None:
        self.running = True

    def stop(self) -> None:
        self.running = False

    def check(self) -> None:
        """A simulated device samples whenever the clock advances: it cannot fall silent or fail (the motor's
        overcurrent is the one simulated fault, see :meth:`SimMotor.check`)."""

    def read(self) -> Batch:
        if not self._pending:
            return self.spec.empty_batch()
        out = self._pending[0] if len(self._pending) == 1 else Batch.concat(self._pending)
        self._pending = []
        return out

    def ingest(self, hist: Trajectory, now: float) -> None:
        """Take every sample measured in (last sample, now] from ``hist`` (rows covering that interval)."""
        k_last = self.clock.last_index(now)
        if k_last < self.next_k:
            return
        k = np.arange(self.next_k, k_last + 1)
        self.next_k = k_last + 1
        d = k / self.clock.rate
        t = np.asarray(self.clock.true_time(d), float)
        cols = self.sample(hist, t, k - self.clock.k0)
        if self.running:
            self._pending.append(Batch(self.name, self.clock.host_ns(t), d, cols))

    def sample(self, hist: Trajectory, t: np.ndarray, index: np.ndarray) -> dict[str, np.ndarray]:
        """The columns of the samples measured at true times ``t`` (``index``: their numbers from 0 at open())."""
        raise NotImplementedError

    def about(self) -> dict[str, Any]:
        """What the session's ``/general`` records of this simulated device: kind, rate, its own settings, clock."""
        return {
            "kind": self.kind or type(self).__name__,
            "rate_hz": self.clock.rate,
            "clock": self.clock.model.model_dump(),
        }


class SimMocap(SampledStream):
    """Motive-like labeled markers (m) at 360 Hz with Gaussian noise, frame numbers from 0 at open()."""

    kind = "SimMocap (Motive-like labeled markers)"

    def __init__(
        self, markers: tuple[str, ...], clock: DeviceClock, rng: np.random.Generator, noise_m: float = 1e-4
    ) -> None:
        super().__init__(mocap_spec(markers), clock)
        self.markers, self.rng, self.noise_m = markers, rng, noise_m

    def sample(self, hist: Trajectory, t: np.ndarray, index: np.ndarray) -> dict[str, np.ndarray]:
        pos = interp_rows(hist.t, hist.channels["markers"], t)
        if self.noise_m > 0:
            pos = pos + self.rng.normal(0.0, self.noise_m, pos.shape)
        return {"data": pos, "frame": index.astype(np.int64), "occluded": np.zeros(pos.shape[:2], bool)}

    def about(self) -> dict[str, Any]:
        return {**super().about(), "markers": list(self.markers), "noise_m": self.noise_m}


class SimLoadCells(SampledStream):
    """Four raw channels at 1 kHz: plate force (mean over the sample period) through the calibration's
    forward model, plus noise; ``sync_edges`` counts the mocap exposures seen so far. ``plate``: whether the scene
    has a plate under the foot (recorded; the walker streams its load cells without one)."""

    kind = "SimLoadCells (4 raw channels, boxcar over the sample period)"

    def __init__(
        self,
        clock: DeviceClock,
        calibration: LoadCellCalibration,
        mocap_clock: DeviceClock,
        rng: np.random.Generator,
        noise_counts: float = 15.0,
        plate: bool = True,
    ) -> None:
        super().__init__(loadcell_spec(), clock)
        self.cal, self.mocap_clock, self.rng, self.noise = calibration, mocap_clock, rng, noise_counts
        self.plate = plate

    def about(self) -> dict[str, Any]:
        extra = {"noise_counts": self.noise, "calibration": self.cal.source, "plate": self.plate}
        return {**super().about(), **extra}

    def sample(self, hist: Trajectory, t: np.ndarray, index: np.ndarray) -> dict[str, np.ndarray]:
        force = box_average(hist.t, hist.channels["force_nt"], t, 1.0 / self.clock.rate)
        counts = self.cal.counts_from_force(force)
        if self.noise > 0:
            counts = counts + self.rng.normal(0.0, self.noise, counts.shape)
        mc = self.mocap_clock
        edges = np.floor(np.asarray(mc.device_time(t)) * mc.rate + 1e-9).astype(np.int64) - mc.k0 + 1
        return {
            "data": np.round(counts).astype(np.int32),
            "seq": index.astype(np.int64),
            "sync_edges": np.maximum(edges, 0),
        }


class SimMotor(SampledStream):
    """The drive as an ODrive in velocity-ramp mode: telemetry at 100 Hz, limits enforced on the device.

    ``torque`` maps trajectory channels to the crank torque (N·m); iq = torque / Kt. Idle: the axis goes to
    IDLE (no current) and the crank coasts down at the ramp rate.
    """

    kind = "SimMotor (ODrive-like velocity ramp)"

    def __init__(
        self,
        clock: DeviceClock,
        ramp: VelocityRamp,
        torque: Callable[[dict[str, np.ndarray]], np.ndarray],
        set_speed: Callable[[float], None],
        rng: np.random.Generator,
        torque_constant: float,
        bus_voltage: float,
        noise: bool = True,
        now: Callable[[], float] = lambda: 0.0,
    ) -> None:
        super().__init__(motor_spec(), clock)
        self.ramp, self.torque, self.set_speed, self.rng = ramp, torque, set_speed, rng
        self.kt, self.vbus, self.noise = torque_constant, bus_voltage, noise
        self.now = now
        self.limits: MotorLimits | None = None
        self.amplitude_mm: float | None = None
        self.axis_state = AXIS_STATE_IDLE
        self.axis_error = 0
        self.fault: str | None = None

    # --- Motor protocol ---------------------------------------------------------------------------
    def arm(self, limits: MotorLimits) -> None:
        if self.fault:
            raise DeviceFault(f"motor: cannot arm after a fault ({self.fault}); close and reopen the rig")
        if limits.max_frequency_hz <= 0 or limits.max_current_a <= 0:
            raise DeviceFault(f"motor: invalid limits {limits}")
        if self.amplitude_mm is not None and abs(limits.amplitude_mm - self.amplitude_mm) > 1e-6:
            raise DeviceFault(
                f"motor: crank amplitude is {self.amplitude_mm:g} mm, limits expect {limits.amplitude_mm:g} mm"
            )
        self.limits = limits
        self.set_speed(0.0)
        self.axis_state = AXIS_STATE_CLOSED_LOOP_CONTROL

    def set_frequency(self, hz: float) -> None:
        if self.fault:
            raise DeviceFault(f"motor: faulted ({self.fault})")
        if self.limits is None or self.axis_state != AXIS_STATE_CLOSED_LOOP_CONTROL:
            raise DeviceFault("motor: set_frequency before arm()")
        if not (math.isfinite(hz) and 0.0 <= hz <= self.limits.max_frequency_hz):
            raise DeviceFault(f"motor: {hz} Hz refused, outside 0..{self.limits.max_frequency_hz:g} Hz")
        self.set_speed(float(hz))

    def idle(self) -> None:
        """Idle now: setpoint 0, no current, the crank coasts down; a state-change telemetry row is sent."""
        was = self.axis_state
        self.set_speed(0.0)
        self.axis_state = AXIS_STATE_IDLE
        if was != AXIS_STATE_IDLE and self.running:
            t = np.array([self.now()])
            row = self._row(t, np.array([self.ramp.theta]), np.array([self.ramp.omega]), np.zeros(1), np.zeros(1))
            self._pending.append(Batch(self.name, self.clock.host_ns(t), np.asarray(self.clock.device_time(t)), row))

    def check(self) -> None:
        if self.fault:
            raise DeviceFault(f"motor: {self.fault}")

    # --- telemetry ---------------------------------------------------------------------------------
    def sample(self, hist: Trajectory, t: np.ndarray, index: np.ndarray) -> dict[str, np.ndarray]:
        ch = hist.channels
        theta = interp_rows(hist.t, ch["theta"], t)
        omega = interp_rows(hist.t, ch["omega"], t)
        setpoint = ch["setpoint"][np.clip(np.searchsorted(hist.t, t, side="right") - 1, 0, len(hist.t) - 1)]
        powered = self.axis_state == AXIS_STATE_CLOSED_LOOP_CONTROL
        if powered:
            tau_rows = self.torque(ch)
            iq = interp_rows(hist.t, tau_rows, t) / self.kt
        else:
            iq = np.zeros(len(t))
        if powered and self.limits is not None and np.any(np.abs(iq) > self.limits.max_current_a):
            i = int(np.argmax(np.abs(iq) > self.limits.max_current_a))
            self.fault = (
                f"current {iq[i]:.2f} A over the {self.limits.max_current_a:g} A limit (CURRENT_LIMIT_VIOLATION)"
            )
            self.axis_error = ERROR_CURRENT_LIMIT_VIOLATION
            self.axis_state = AXIS_STATE_IDLE
            self.set_speed(0.0)
        return self._row(t, theta, omega, setpoint, iq)

    def _row(
        self, t: np.ndarray, theta: np.ndarray, omega: np.ndarray, setpoint: np.ndarray, iq: np.ndarray
    ) -> dict[str, np.ndarray]:
        n = len(t)
        pos = np.round(theta / (2 * math.pi) * 8192.0) / 8192.0  # 13-bit encoder counts → turns
        vel = omega.astype(float)
        iq = iq.astype(float)
        vbus = self.vbus - 0.05 * np.abs(iq)
        if self.noise:
            vel = vel + self.rng.normal(0.0, 0.01, n)
            iq = iq + self.rng.normal(0.0, 0.02, n)
            vbus = vbus + self.rng.normal(0.0, 0.02, n)
        return {
            "position": pos,
            "velocity": vel,
            "velocity_setpoint": setpoint.astype(float),
            "iq_measured": iq,
            "bus_voltage": vbus,
            "axis_state": np.full(n, self.axis_state, np.int32),
            "axis_error": np.full(n, self.axis_error, np.int64),
        }
