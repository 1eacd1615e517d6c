"""Pydantic models of the protocol YAML; every error names the file, the field, the value and the reason.

Numbers are strict: finite (no ``.nan``/``.inf``), ``true``/``false`` are not numbers, strings are not numbers.
Files are read through :mod:`beambench.common.yaml_config` (size, nesting and alias caps).
"""

from __future__ import annotations

import math
import re
import string
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator, model_validator

from beambench.acquisition.protocol.scenes import runnable_names, scene_info
from beambench.common.names import MAX_NAME_BYTES, check_name
from beambench.common.yaml_config import MISSING as _MISSING
from beambench.common.yaml_config import ConfigError, load_yaml_file, parse_yaml, validate

Backend = Literal["sim", "emulated", "hardware"]


def _runnable_scene(name: str) -> str:
    known = runnable_names()
    if name not in known:
        choices = ", ".join(repr(n) for n in known[:-1]) + f" or {known[-1]!r}"
        raise ValueError(f"Input should be {choices}")
    return name


# the scenes a protocol may run, as declared in beambench.acquisition.protocol.scenes (contact, walker, release)
RigKind = Annotated[str, AfterValidator(_runnable_scene)]
Integrator = Literal["euler", "implicitfast", "implicit", "rk4", "discrete"]
BACKENDS: tuple[str, ...] = get_args(Backend)


__all__ = ["BACKENDS", "Protocol", "RigFile", "load_protocol", "load_rig_file", "parse_protocol"]

MAX_STEPS = 10_000  # a sweep longer than this is a typo (1e-9 Hz steps), not a measurement
# the lowest drive frequency (Hz) other than 0: one period in 100 s; 1e-320 Hz is a typo, not a measurement
MIN_FREQUENCY_HZ = 0.01
# the finest sim.timestep (s): 25x finer than the contact rig's reference (2.5e-5 s); and the most physics steps a
# run may take at a given timestep (about a day of MuJoCo stepping): both bound what is allocated
MIN_TIMESTEP_S = 1e-6
MAX_SIM_STEPS = 10**10


class _Model(BaseModel):
    # strict: YAML already types its values, so "5" is not 5 and true is not 1; and every float is finite
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


class Sweep(_Model):
    """Frequencies in Hz: ``start``/``stop``/``step`` (inclusive) or an explicit ``frequencies`` list.

    ``direction``: ``up`` runs them in the order given (start → stop, or the list as written), ``down`` in reverse,
    ``both`` up then back down in one session (the turning frequency once). ``repeats``: each frequency K times,
    ``interleaved`` (default: the whole sweep K times, so a slow drift spreads over every frequency alike) or in
    ``blocks`` (each frequency K times in a row).
    """

    start: float | None = Field(None, ge=MIN_FREQUENCY_HZ)
    stop: float | None = Field(None, ge=MIN_FREQUENCY_HZ)
    step: float | None = Field(None, gt=0)
    frequencies: list[float] | None = Field(None, max_length=MAX_STEPS)
    direction: Literal["up", "down", "both"] = "up"
    repeats: int = Field(1, ge=1, le=100)
    repeat_order: Literal["interleaved", "blocks"] = "interleaved"

    @field_validator("frequencies")
    @classmethod
    def _not_vanishing(cls, v: list[float] | None) -> list[float] | None:
        tiny = next((f for f in v or [] if 0 < f < MIN_FREQUENCY_HZ), None)
        if tiny is not None:
            raise ValueError(f"{tiny:g} Hz: a frequency is 0 or at least {MIN_FREQUENCY_HZ:g} Hz")
        return v

    @model_validator(mode="after")
    def _one_form(self) -> Sweep:
        ranged = (self.start, self.stop, self.step)
        if self.frequencies is not None:
            if any(v is not None for v in ranged):
                raise ValueError("give either start/stop/step or frequencies, not both")
            if not self.frequencies or any(f < 0 for f in self.frequencies):
                raise ValueError("frequencies must be a non-empty list of numbers >= 0")
        elif any(v is None for v in ranged):
            raise ValueError("needs start, stop and step (Hz), or a frequencies list")
        elif self.stop < self.start:  # type: ignore[operator]
            raise ValueError("stop must be >= start")
        elif self.n_steps() > MAX_STEPS:
            raise ValueError(f"{self.n_steps():.3g} steps (start/stop/step): more than {MAX_STEPS}")
        else:
            self._check_lands_on_stop()
        return self

    def _check_lands_on_stop(self) -> None:
        """``stop`` is inclusive: a step that jumps over it (1 to 10 by 4: 1, 5, 9) is refused, naming the field."""
        start, stop, step = float(self.start), float(self.stop), float(self.step)  # type: ignore[arg-type]
        n = (stop - start) / step
        if abs(n - round(n)) <= 1e-6 * max(1.0, n):
            return
        last = start + math.floor(n) * step
        fits = sorted({round((stop - start) / k, 6) for k in (math.floor(n), math.ceil(n)) if k >= 1})
        raise ValueError(
            f"step = {step:g} does not land on stop = {stop:g} from start = {start:g} (the last step would be "
            f"{last:g}; stop is inclusive): use step {' or '.join(f'{f:g}' for f in fits)}, or stop {last:g}"
        )

    def n_steps(self) -> float:
        """How many steps, computed without building them (a float: may be astronomically large)."""
        if self.frequencies is not None:
            return len(self.frequencies)
        n = (self.stop - self.start) / self.step  # type: ignore[operator]
        return math.floor(n + 0.5) + 1 if math.isfinite(n) else math.inf

    def values(self) -> list[float]:
        if self.frequencies is not None:
            return [float(f) for f in self.frequencies]
        n = round((self.stop - self.start) / self.step)  # type: ignore[operator]
        if n + 1 > MAX_STEPS:
            raise ValueError(f"{n + 1} steps: more than {MAX_STEPS}")
        vals = [round(self.start + i * self.step, 9) for i in range(n + 1)]  # type: ignore[operator]
        return [v for v in vals if v <= self.stop + 1e-9]  # type: ignore[operator]


class Reference(_Model):
    """A reference step at ``frequency_hz`` first, after every ``every_steps`` sweep steps, and last: its drift
    over the session tells a slow change of the rig (e.g. a beam warming up) from a frequency effect."""

    frequency_hz: float = Field(ge=MIN_FREQUENCY_HZ)
    every_steps: int = Field(gt=0, le=MAX_STEPS)


class Limits(_Model):
    """Hard limits checked before anything moves."""

    max_frequency_hz: float = Field(45.0, gt=0, le=200)
    max_current_a: float = Field(10.0, gt=0, le=60)
    max_amplitude_mm: float = Field(3.0, gt=0, le=10)


class ClockModel(_Model):
    """A simulated device clock: offset, drift and receive jitter (for testing sync against a known truth)."""

    offset_s: float = Field(0.0, ge=-1e6, le=1e6)
    drift_ppm: float = Field(0.0, ge=-1e5, le=1e5)
    jitter_s: float = Field(0.0, ge=0, le=10)
    latency_s: float = Field(0.0005, ge=0, le=10)


class ThermalDrift(_Model):
    """The contact twin's thermal drift (``sim.thermal_drift``; model, parameter ranges and sources:
    :mod:`beambench.sim.models.thermal`): the beam warms with the drive power and its stiffness falls by
    ``alpha_per_k`` per kelvin, relaxing with ``tau_s``. Off when absent."""

    alpha_per_k: float = Field(0.01, gt=0, le=0.2)  # relative stiffness fall per K (TPU: 0.005-0.02)
    tau_s: float = Field(100.0, gt=0, le=86_400)  # cooling time constant (0.5 mm strip in still air: 40-130 s)
    # J/K; None: the beam's mass x 1.8 kJ/(kg K) (TPU); smaller compresses a long run's warming into seconds
    heat_capacity_j_per_k: float | None = Field(None, gt=0, le=10_000)
    heated_fraction: float = Field(1.0, gt=0, le=1)  # share of the drive power into the beam that heats it


CLOCK_SUFFIX = "_clock"


class SimOptions(_Model):
    """Options of the MuJoCo backend."""

    model: str = Field("prb3", min_length=1, max_length=40)  # checked against the registry by session.checks
    params: str = Field("paper", min_length=1, max_length=400)
    timestep: float | None = Field(None, ge=MIN_TIMESTEP_S, le=0.01)
    integrator: Integrator = "implicitfast"
    tolerance_mm: float | None = Field(None, gt=0)
    # h' (mm) from the foot's unloaded position; None: the parameter set's rig.plate_gap (paper: 5.5 mm)
    plate_gap_mm: float | None = Field(None, ge=-2, le=50)
    twist_deg: float = Field(90.0, ge=-360, le=360)
    noise: bool = True
    seed: int = Field(0, ge=0, le=2**32 - 1)
    # the sweep (walker, contact rig) computed as this many consecutive parts in parallel (one core each), each part
    # after the first pre-settled at its first frequency: the state is not carried across the cuts; the contact rig
    # checks each cut and moves it where the regimes differ (beambench.backends.lookahead)
    segments: int = Field(1, ge=1, le=8)
    # each simulated device's clock, by stream name (mocap, loadcell, motor, any stream the sim backend registers;
    # each name checked against them, with the file, by beambench.session.slices.check_clocks); a stream not named
    # keeps the default clock
    clocks: dict[str, ClockModel] = Field(default_factory=dict, max_length=64)
    thermal_drift: ThermalDrift | None = None  # contact rig only

    @model_validator(mode="before")
    @classmethod
    def _clock_keys(cls, data: Any) -> Any:
        """``<stream>_clock: {...}`` (the form before ``clocks:``) is ``clocks: {<stream>: {...}}``."""
        if not isinstance(data, dict):
            return data
        legacy = {k: k.removesuffix(CLOCK_SUFFIX) for k in data if isinstance(k, str) and k.endswith(CLOCK_SUFFIX)}
        if not legacy:
            return data
        clocks = data.get("clocks", {})
        if not isinstance(clocks, dict):
            return data  # the field's own check says what is wrong with it
        both = sorted(k for k, name in legacy.items() if name in clocks)
        if both:
            raise ValueError(f"{both[0]} and clocks.{legacy[both[0]]} both given: keep one")
        out = {k: v for k, v in data.items() if k not in legacy}
        out["clocks"] = {**clocks, **{name: data[k] for k, name in legacy.items()}}
        return out


class Release(_Model):
    """The release test (``rig: release``): a load hangs at the tip, then is released; no drive."""

    load_g: float = Field(200.0, gt=0, le=2000)
    markers: int = Field(3, ge=1, le=3)


class Monitors(_Model):
    """What pauses a step's recording (its window then runs longer) and when a pause becomes a fault."""

    mocap_lost_s: float | None = Field(0.25, gt=0, le=60)  # no complete mocap frame this long: pause; null: off
    max_pause_s: float = Field(30.0, gt=0, le=3600)  # a longer pause stops the run (motor idle, data saved)


class TrackSegment(_Model):
    """One segment of a speed profile: a target speed along the forward axis (mm/s; the sign is the direction,
    0 stands the walker) held for ``hold_s``."""

    speed_mm_s: float = Field(ge=-1000, le=1000)
    hold_s: float = Field(gt=0, le=3600)


class TrackControl(_Model):
    """The speed controller's settings (:mod:`beambench.acquisition.control.speed_controller`); the defaults suit the walker."""

    feedback: bool = True  # false: feed-forward from the map alone
    kp: float = Field(1.0, ge=0, le=10)  # proportional gain on the speed error (mm/s per mm/s)
    ki_per_s: float = Field(2.0, ge=0, le=50)  # integral gain (1/s)
    # the integrator runs only while |error| <= integrate_within × |target| + 10 mm/s (not during big transients)
    integrate_within: float = Field(0.25, ge=0, le=10)
    # frequency rate limit (Hz/s), and the motor's ramp the controller reckons with: below the walker drive's
    # ramp (calibration/rig.yaml walker.vel_ramp_rate_turn_s2, 200 turn/s²)
    rate_hz_s: float = Field(180.0, gt=0, le=1000)
    control_s: float = Field(0.05, ge=0.005, le=1)  # control period (rig time)
    window_periods: float = Field(4.0, gt=0, le=100)  # measured speed: slope over this many drive periods
    min_window_s: float = Field(0.15, gt=0, le=10)
    max_window_s: float = Field(0.5, gt=0, le=10)
    # a step: the drive set to the map's frequency for target + lead × (target − the speed measured at the step),
    # held until the measured speed, carried on at its acceleration, will get there; at most 4 × body_tau_s
    body_tau_s: float = Field(1.0, gt=0, le=10)
    lead: float = Field(1.5, ge=0, le=10)


class Track(_Model):
    """``track:``: walk a speed profile from a speed map. ``map``: a walker session (``.h5``), its ``steps.csv``,
    or ``twin`` (run this protocol's ``sweep`` on the sim first and use its speeds)."""

    map: str = Field(min_length=1, max_length=4096)
    segments: list[TrackSegment] = Field(min_length=1, max_length=MAX_STEPS)
    settle_s: float = Field(1.0, ge=0, le=60)  # each segment's settling time before its record window (analysis)
    control: TrackControl = TrackControl()

    @model_validator(mode="after")
    def _holds_exceed_settling(self) -> Track:
        for i, seg in enumerate(self.segments):
            if seg.hold_s <= self.settle_s:
                raise ValueError(f"segments[{i}].hold_s = {seg.hold_s:g} s must exceed settle_s = {self.settle_s:g} s")
        if self.control.min_window_s > self.control.max_window_s:
            raise ValueError("control.min_window_s must be <= control.max_window_s")
        return self


class Output(_Model):
    """Session file naming; ``name`` is a template with ``{protocol}``, ``{rig}``, ``{backend}``, ``{date}``."""

    name: str = Field("{protocol}_{backend}_{date}", min_length=1, max_length=400)

    @field_validator("name")
    @classmethod
    def _template_formats(cls, v: str) -> str:
        check_name(format_name(v, "p", "contact", "sim", "20260101-000000"), "the name it makes")
        return v


NAME_FIELDS = ("protocol", "rig", "backend", "date")  # the fields an ``output.name`` template may use


def format_name(template: str, protocol: str, rig: str, backend: str, date: str) -> str:
    """Fill an ``output.name`` template; any template problem is a ValueError with one short line."""
    try:
        _check_template(template)
        return template.format(protocol=protocol, rig=rig, backend=backend, date=date)
    except (KeyError, IndexError, ValueError, AttributeError, TypeError) as exc:
        known = ", ".join(f"{{{f}}}" for f in NAME_FIELDS)
        raise ValueError(f"bad template ({type(exc).__name__}: {str(exc)[:60]}); use {known}") from None


def _check_template(template: str) -> None:
    """Refuse, before formatting, any field but the documented :data:`NAME_FIELDS` (so no attribute or index access,
    ``{protocol.__class__}``, and no positional ``{}``), a width or precision that would make a name longer than
    :data:`MAX_NAME_BYTES` (``{protocol:>300000000}`` would build 300 MB first) and nested fields in a spec."""
    for _, field, spec, _ in string.Formatter().parse(template):
        if field is None:
            continue
        if field not in NAME_FIELDS:
            raise ValueError(f"unknown field {{{field[:24]}}}")
        if not spec:
            continue
        if "{" in spec or "}" in spec:
            raise ValueError(f"nested field in {spec[:12]!r}")
        widths = [int(d) for d in re.findall(r"\d+", spec)] if len(spec) <= 20 else [MAX_NAME_BYTES + 1]
        if max(widths, default=0) > MAX_NAME_BYTES:
            raise ValueError(f"format width over {MAX_NAME_BYTES} in {spec[:12]!r}")


class Protocol(_Model):
    """A measurement protocol: a frequency sweep on a rig."""

    name: str = Field("protocol", min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = Field("", max_length=20_000)
    rig: RigKind = "contact"
    backend: Backend = "sim"
    sweep: Sweep | None = None  # required, except with track: and a map file (track: map: twin sweeps it)
    reference: Reference | None = None
    settle_s: float = Field(2.0, ge=0, le=600)
    record_s: float = Field(5.0, gt=0, le=3600)
    amplitude_mm: float = Field(2.0, gt=0, le=1000)
    limits: Limits = Limits()
    sim: SimOptions = SimOptions()
    release: Release = Release()
    monitors: Monitors = Monitors()
    output: Output = Output()
    rig_file: str | None = Field(None, max_length=4096)
    track: Track | None = None  # walk a speed profile instead of sweeping (a rig whose scene walks)

    @model_validator(mode="after")
    def _driven_rigs_need_frequencies(self) -> Protocol:
        if self.track is not None:
            if not scene_info(self.rig).walks:
                walkers = " or ".join(n for n in runnable_names() if scene_info(n).walks)
                raise ValueError(f"track: applies to rig: {walkers} only (this protocol is rig: {self.rig})")
            if self.track.map == "twin" and self.sweep is None:
                raise ValueError("track: map: twin needs a sweep: (the twin's own speed map is measured on it)")
        elif self.sweep is None:
            raise ValueError("sweep: Field required (or a track: section with a map file)")
        if self.sweep is not None and scene_info(self.rig).driven and min(self.sweep.values()) <= 0:
            undriven = " or ".join(n for n in runnable_names() if not scene_info(n).driven)
            raise ValueError(f"sweep: frequencies must be > 0 Hz on the {self.rig} rig (0 is for rig: {undriven})")
        if self.track is not None and self.reference is not None:
            raise ValueError("reference: not with track: (a speed profile has no sweep to interleave)")
        swept_down = self.sweep is not None and self.sweep.direction != "up"
        if not scene_info(self.rig).driven and (self.reference is not None or swept_down):
            raise ValueError(f"reference and sweep.direction are for driven rigs, not {self.rig}")
        n = self.n_planned_steps()
        if n > MAX_STEPS:
            raise ValueError(f"sweep: {n:.3g} steps with direction, repeats and reference: more than {MAX_STEPS}")
        self._check_sim_steps(n)
        return self

    def _check_sim_steps(self, n_steps: float) -> None:
        """A fixed ``sim.timestep`` may not ask for more than :data:`MAX_SIM_STEPS` physics steps in all."""
        dt = self.sim.timestep
        if dt is None:
            return
        if self.track is not None:
            rig_s = sum(seg.hold_s for seg in self.track.segments)
        else:
            rig_s = n_steps * (self.settle_s + self.record_s)
        if rig_s / dt > MAX_SIM_STEPS:
            raise ValueError(
                f"sim.timestep = {dt:g} s over {rig_s:g} s of rig time is {rig_s / dt:.3g} physics steps: more than "
                f"{MAX_SIM_STEPS:.0e} (a coarser timestep, or fewer or shorter steps)"
            )

    def n_planned_steps(self) -> float:
        """Steps the run makes: the sweep (both directions, repeats) plus reference steps."""
        if self.track is not None or self.sweep is None:
            return float(len(self.track.segments)) if self.track is not None else 0.0
        n = self.sweep.n_steps()
        if self.sweep.direction == "both":
            n = 2 * n - 1
        n *= self.sweep.repeats
        if self.reference is not None and math.isfinite(n):
            n += math.ceil(n / self.reference.every_steps) + 1
        return n

    def limit_violations(self) -> list[tuple[str, Any, str]]:
        """(field, value, reason) for every commanded value over its limit."""
        out: list[tuple[str, Any, str]] = []
        fmax = max(
            (self.sweep.values() if self.sweep is not None else [0.0])
            + ([self.reference.frequency_hz] if self.reference else [])
        )
        if fmax > self.limits.max_frequency_hz:
            out.append(("sweep", fmax, f"exceeds limits.max_frequency_hz = {self.limits.max_frequency_hz:g} Hz"))
        if self.amplitude_mm > self.limits.max_amplitude_mm:
            out.append(
                (
                    "amplitude_mm",
                    self.amplitude_mm,
                    f"exceeds limits.max_amplitude_mm = {self.limits.max_amplitude_mm:g} mm",
                )
            )
        return out


SWEEP_FILE_KEYS = frozenset({"scene", "base", "grid", "points", "sample_dt"})


def _not_a_sweep_file(data: Any, file: str) -> None:
    if isinstance(data, dict) and "sweep" not in data and SWEEP_FILE_KEYS & set(data):
        raise ConfigError(
            file,
            "(file)",
            _MISSING,
            f"this is a sweep file (it has {sorted(SWEEP_FILE_KEYS & set(data))[0]}): "
            "run it with `beambench sweep`, not `beambench run`",
        )


def _sweep_or_track(data: Any, file: str) -> None:
    """The one-line errors of a missing ``sweep:`` (the model's own check would name the top level instead)."""
    if not isinstance(data, dict) or "sweep" in data:
        return
    track = data.get("track")
    if not isinstance(track, dict):
        raise ConfigError(file, "sweep", _MISSING, "Field required (or a track: section with a map file)")
    if track.get("map") == "twin":
        raise ConfigError(file, "sweep", _MISSING, "Field required: track: map: twin measures its map on this sweep")


def parse_protocol(text: str, file: str = "<protocol>") -> Protocol:
    """Parse and validate protocol YAML text; raise :class:`ConfigError` naming the first problem."""
    data = parse_yaml(text, file)
    if not isinstance(data, dict):
        raise ConfigError(file, "(top level)", _MISSING, "expected a mapping of protocol fields")
    _not_a_sweep_file(data, file)
    _sweep_or_track(data, file)
    return validate(Protocol, data, file, what="protocol fields")


def load_protocol(path: str | Path) -> tuple[Protocol, str]:
    """Read a protocol file; returns the validated model and its text (stored verbatim in the session)."""
    data, text = load_yaml_file(path)
    _not_a_sweep_file(data, str(path))
    _sweep_or_track(data, str(path))
    return validate(Protocol, data, str(path), what="protocol fields"), text


# --- rig wiring -----------------------------------------------------------------------------------------
class RigSection(_Model):
    """A section of the rig file (strict, every field known); a device stream that brings its own section
    subclasses it (``@device_stream(name, wiring=...)``, :mod:`beambench.devices.streams.registry`)."""


class NatNetWiring(RigSection):
    """Where Motive is and how frames arrive."""

    server_address: str = "127.0.0.1"
    local_address: str = "127.0.0.1"
    command_port: int = Field(1510, ge=1, le=65535)
    data_port: int = Field(1511, ge=1, le=65535)
    multicast_address: str = "239.255.42.99"
    multicast: bool = True
    bitstream_version: str | None = None  # ask a NatNet 4.x server for "3.0", "4.0" or "4.1"; else as it sends
    # no frame for this long is a device fault (shorter outages: the protocol's mocap_lost_s monitor pauses)
    silence_timeout_s: float | None = Field(5.0, gt=0, le=600)
    markers: dict[str, str | int] = Field(
        default_factory=lambda: dict[str, str | int](stage="1:1", tip="1:2", foot="1:3")
    )


class Geometry(RigSection):
    """The mocap's world frame as calibrated (Motive's default is y up); stored in each session for analysis."""

    up_axis: str = Field("y", pattern=r"^[+-]?[xyz]$")
    forward_axis: str = Field("x", pattern=r"^[+-]?[xyz]$")  # the walker's direction of travel


class OdriveWiring(RigSection):
    """How the ODrive is reached: CAN Simple over python-can, or USB through the ``odrive`` package."""

    transport: Literal["can", "usb"] = "can"
    interface: str = "socketcan"
    channel: str = "can0"
    bitrate: int = 250000
    node_id: int = Field(0, ge=0, le=63)
    axis: int = Field(0, ge=0, le=1)
    serial_number: str | None = None
    watchdog_timeout_s: float = Field(0.5, gt=0, le=5)
    # heartbeats come every 100 ms by default (axis.config.can.heartbeat_rate_ms): ten periods
    heartbeat_timeout_s: float = Field(1.0, gt=0, le=10)
    telemetry_timeout_s: float | None = Field(1.0, gt=0, le=10)  # Encoder_Estimates (every 10 ms by default)


class LoadCellWiring(RigSection):
    """The load-cell microcontroller's serial port."""

    port: str = "/dev/ttyACM0"
    baudrate: int = 921600
    silence_timeout_s: float | None = Field(1.0, gt=0, le=60)  # no frame for this long (1 kHz board): fault


class WalkerDrive(RigSection):
    """The walker's motor on the ODrive (``calibration/rig.yaml`` ``walker:``): what the ODrive must be configured
    with for it, and what the emulated ODrive plays. Defaults: Maxon EC 45 flat Ø42.9 mm 30 W with Hall sensors,
    article 200142 (12 V winding), datasheet May 2012 edition (line numbers in the comments)."""

    motor: str = "Maxon EC 45 flat 30 W, 200142 (Hall sensors, 12 V winding)"
    feedback: Literal["hall", "encoder"] = "hall"  # ODrive encoder mode: Hall (the motor's own sensors)
    pole_pairs: int = Field(8, ge=1, le=50)  # EC 45 flat: 16 magnet poles
    torque_constant_nm_a: float = Field(0.0255, gt=0)  # line 12: 25.5 mN·m/A
    phase_resistance_ohm: float = Field(0.6, gt=0)  # line 10: 1.2 Ω phase to phase (ODrive wants phase)
    phase_inductance_h: float = Field(2.8e-4, gt=0)  # line 11: 0.56 mH phase to phase
    rotor_inertia_kg_m2: float = Field(9.25e-6, gt=0)  # line 16: 92.5 g·cm²
    load_inertia_kg_m2: float = Field(4.0e-6, ge=0)  # the 40 g offset mass at 10 mm (paper; radius guessed)
    continuous_current_a: float = Field(2.03, gt=0, le=60)  # line 6: nominal (max. continuous) current
    current_lim_a: float = Field(6.0, gt=0, le=60)  # ODrive current_lim: ~3× line 6 (twin: 5.1 A peaks at 80 Hz)
    vel_limit_turn_s: float = Field(88.0, gt=0, le=250)  # 80 Hz = 80 turn/s, ×1.1; 24 V reach 150 turn/s (line 13)
    # ODrive controller.config.vel_ramp_rate (turn/s², set over USB): 200 turn/s² needs (9.25e-6 + 4.0e-6 kg·m²) ×
    # 2π × 200 = 16.7 mN·m = 0.65 A at 25.5 mN·m/A (lines 12, 16), a third of line 6's 2.03 A continuous current;
    # the sim twin shares it (WalkerParams.vel_ramp_rate) and draws ≤ 2.7 A peaks with it (benchmarks/bench_track.py)
    vel_ramp_rate_turn_s2: float = Field(200.0, gt=0, le=1000)


class RigFile(_Model):
    """``calibration/rig.yaml``: server/client addresses, CAN channel and node id, serial port, marker ids."""

    natnet: NatNetWiring = NatNetWiring()
    odrive: OdriveWiring = OdriveWiring()
    loadcell: LoadCellWiring = LoadCellWiring()
    loadcell_calibration: str = "loadcells.yaml"
    geometry: Geometry = Geometry()
    walker: WalkerDrive = Field(default_factory=WalkerDrive)


def load_rig_file(path: str | Path, model: type[RigFile] = RigFile) -> RigFile:
    """Read and validate a rig file, with the same one-line errors and caps as protocols; ``model``: the rig
    file's model with the sections the registered device streams bring
    (:func:`beambench.backends.hardware.rig_file_model`)."""
    data, _ = load_yaml_file(path)
    return validate(model, data, str(path), what="rig wiring fields")
