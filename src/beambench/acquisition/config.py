"""Pydantic models of the protocol YAML; every error names the file, the field, the value and the reason."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, get_args

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from beambench.common.errors import BeambenchError

Backend = Literal["sim", "emulated", "hardware"]
RigKind = Literal["contact", "walker", "release"]
Integrator = Literal["euler", "implicitfast", "implicit", "rk4", "discrete"]
BACKENDS: tuple[str, ...] = get_args(Backend)


class ConfigError(BeambenchError, ValueError):
    """A protocol or rig file is invalid. ``str()`` is one line: file, field, value, reason."""

    def __init__(self, file: str, field: str, value: Any, reason: str) -> None:
        self.file, self.field, self.value, self.reason = file, field, value, reason
        shown = "" if value is _MISSING else f" = {value!r}"
        super().__init__(f"{file}: {field}{shown}: {reason}")


_MISSING = object()


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Sweep(_Model):
    """Frequencies in Hz: ``start``/``stop``/``step`` (inclusive) or an explicit ``frequencies`` list."""

    start: float | None = Field(None, gt=0)
    stop: float | None = Field(None, gt=0)
    step: float | None = Field(None, gt=0)
    frequencies: list[float] | None = None

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
        return self

    def values(self) -> list[float]:
        if self.frequencies is not None:
            return [float(f) for f in self.frequencies]
        n = round((self.stop - self.start) / self.step)  # type: ignore[operator]
        vals = [round(self.start + i * self.step, 9) for i in range(n + 1)]  # type: ignore[operator]
        return [v for v in vals if v <= self.stop + 1e-9]  # type: ignore[operator]


class Limits(_Model):
    """Hard limits checked before anything moves."""

    max_frequency_hz: float = Field(45.0, gt=0, le=200)
    max_current_a: float = Field(10.0, gt=0, le=60)
    max_amplitude_mm: float = Field(3.0, gt=0, le=10)


class ClockModel(_Model):
    """A simulated device clock: offset, drift and receive jitter (for testing sync against a known truth)."""

    offset_s: float = 0.0
    drift_ppm: float = 0.0
    jitter_s: float = Field(0.0, ge=0)
    latency_s: float = Field(0.0005, ge=0)


class SimOptions(_Model):
    """Options of the MuJoCo backend."""

    model: str = "prb3"
    params: str = "paper"
    timestep: float | None = Field(None, gt=0, le=0.01)
    integrator: Integrator = "implicitfast"
    tolerance_mm: float | None = Field(None, gt=0)
    # h' (mm) from the foot's unloaded position; None: the parameter set's rig.plate_gap (paper: 5.5 mm)
    plate_gap_mm: float | None = Field(None, ge=-2, le=50)
    twist_deg: float = 90.0
    noise: bool = True
    seed: int = 0
    mocap_clock: ClockModel = ClockModel()
    loadcell_clock: ClockModel = ClockModel()
    motor_clock: ClockModel = ClockModel()


class Release(_Model):
    """The release test (``rig: release``): a load hangs at the tip, then is released; no drive."""

    load_g: float = Field(200.0, gt=0, le=2000)
    markers: int = Field(3, ge=1, le=3)


class Monitors(_Model):
    """What pauses a step's recording (its window then runs longer) and when a pause becomes a fault."""

    mocap_lost_s: float | None = Field(0.25, gt=0, le=60)  # no complete mocap frame this long: pause; null: off
    max_pause_s: float = Field(30.0, gt=0, le=3600)  # a longer pause stops the run (motor idle, data saved)


class Output(_Model):
    """Session file naming; ``name`` is a template with ``{protocol}``, ``{rig}``, ``{backend}``, ``{date}``."""

    name: str = "{protocol}_{backend}_{date}"


class Protocol(_Model):
    """A measurement protocol: a frequency sweep on a rig."""

    name: str = Field("protocol", min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = ""
    rig: RigKind = "contact"
    backend: Backend = "sim"
    sweep: Sweep
    settle_s: float = Field(2.0, ge=0, le=600)
    record_s: float = Field(5.0, gt=0, le=3600)
    amplitude_mm: float = Field(2.0, gt=0)
    limits: Limits = Limits()
    sim: SimOptions = SimOptions()
    release: Release = Release()
    monitors: Monitors = Monitors()
    output: Output = Output()
    rig_file: str | None = None

    @model_validator(mode="after")
    def _driven_rigs_need_frequencies(self) -> Protocol:
        if self.rig != "release" and min(self.sweep.values()) <= 0:
            raise ValueError(f"sweep: frequencies must be > 0 Hz on the {self.rig} rig (0 is for rig: release)")
        return self

    def limit_violations(self) -> list[tuple[str, Any, str]]:
        """(field, value, reason) for every commanded value over its limit."""
        out: list[tuple[str, Any, str]] = []
        fmax = max(self.sweep.values())
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


def _field_path(loc: tuple[Any, ...]) -> str:
    return ".".join(str(p) for p in loc if not str(p).startswith("function-")) or "(top level)"


def _lookup(data: Any, loc: tuple[Any, ...]) -> Any:
    for key in loc:
        try:
            data = data[key]
        except (KeyError, IndexError, TypeError):
            return _MISSING
    return data


def parse_protocol(text: str, file: str = "<protocol>") -> Protocol:
    """Parse and validate protocol YAML text; raise :class:`ConfigError` naming the first problem."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "YAML"
        raise ConfigError(file, where, _MISSING, f"not valid YAML ({getattr(exc, 'problem', exc)})") from None
    if not isinstance(data, dict):
        raise ConfigError(file, "(top level)", _MISSING, "expected a mapping of protocol fields")
    try:
        return Protocol.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = tuple(err["loc"])
        value = _lookup(data, loc)
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown field"
        raise ConfigError(file, _field_path(loc), value, msg) from None


def load_protocol(path: str | Path) -> tuple[Protocol, str]:
    """Read a protocol file; returns the validated model and its text (stored verbatim in the session)."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ConfigError(str(p), "(file)", _MISSING, exc.strerror or str(exc)) from None
    return parse_protocol(text, str(p)), text


# --- rig wiring -----------------------------------------------------------------------------------------
class NatNetWiring(_Model):
    """Where Motive is and how frames arrive."""

    server_address: str = "127.0.0.1"
    local_address: str = "127.0.0.1"
    command_port: int = Field(1510, ge=1, le=65535)
    data_port: int = Field(1511, ge=1, le=65535)
    multicast_address: str = "239.255.42.99"
    multicast: bool = True
    bitstream_version: str | None = None  # ask a NatNet 4.x server for "3.0", "4.0" or "4.1"; else as it sends
    markers: dict[str, str | int] = Field(default_factory=lambda: {"stage": "1:1", "tip": "1:2", "foot": "1:3"})


class Geometry(_Model):
    """The mocap's world frame as calibrated (Motive's default is y up); stored in each session for analysis."""

    up_axis: str = Field("y", pattern=r"^[+-]?[xyz]$")
    forward_axis: str = Field("x", pattern=r"^[+-]?[xyz]$")  # the walker's direction of travel


class OdriveWiring(_Model):
    """How the ODrive is reached: CAN Simple over python-can, or USB through the ``odrive`` package."""

    transport: Literal["can", "usb"] = "can"
    interface: str = "socketcan"
    channel: str = "can0"
    bitrate: int = 250000
    node_id: int = Field(0, ge=0, le=63)
    axis: int = Field(0, ge=0, le=1)
    serial_number: str | None = None
    watchdog_timeout_s: float = Field(0.5, gt=0, le=5)


class LoadCellWiring(_Model):
    """The load-cell microcontroller's serial port."""

    port: str = "/dev/ttyACM0"
    baudrate: int = 921600


class WalkerDrive(_Model):
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
    current_lim_a: float = Field(4.0, gt=0, le=60)  # ODrive current_lim: ~2× line 6 for short peaks (twin: 2.7 A)
    vel_limit_turn_s: float = Field(88.0, gt=0, le=250)  # 80 Hz = 80 turn/s, ×1.1; 24 V reach 150 turn/s (line 13)


class RigFile(_Model):
    """``calibration/rig.yaml``: server/client addresses, CAN channel and node id, serial port, marker ids."""

    natnet: NatNetWiring = NatNetWiring()
    odrive: OdriveWiring = OdriveWiring()
    loadcell: LoadCellWiring = LoadCellWiring()
    loadcell_calibration: str = "loadcells.yaml"
    geometry: Geometry = Geometry()
    walker: WalkerDrive = Field(default_factory=WalkerDrive)


def load_rig_file(path: str | Path) -> RigFile:
    """Read and validate a rig file, with the same one-line errors as protocols."""
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text()) or {}
    except OSError as exc:
        raise ConfigError(str(p), "(file)", _MISSING, exc.strerror or str(exc)) from None
    except yaml.YAMLError as exc:
        raise ConfigError(str(p), "(file)", _MISSING, f"not valid YAML ({exc})") from None
    try:
        return RigFile.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = tuple(err["loc"])
        msg = "unknown field" if err["type"] == "extra_forbidden" else err["msg"].removeprefix("Value error, ")
        raise ConfigError(str(p), _field_path(loc), _lookup(data, loc), msg) from None
