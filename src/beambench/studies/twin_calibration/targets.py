"""What ``beambench calibrate sim`` fits the twin to: published numbers (a targets YAML) or a measured session.

Targets file (``--targets``), contact rig::

    rig: contact
    continuous_below_hz: 18   # the foot never leaves the plate below this frequency
    half_at_hz: 26            # lowest frequency with one contact every two drive cycles
    third_at_hz: 38           # lowest frequency with one contact every three drive cycles
    tangential_sign: {26: -1, 40: 1}   # optional
    tolerance_hz: 2           # optional: how close each transition must come (default ± 2 Hz)

Every transition is optional, but at least one is needed, and they must be ordered
(continuous edge ≤ ½ < ⅓). ``tangential_sign`` uses the sign convention of ``steps.csv``: the sign of the mean
tangential (drive-axis, +x = the stage's positive travel) force of the foot on the plate while in contact.

Walker (registered by the walker rig's calibrator)::

    rig: walker
    speed_mm_s: {23: -35.7, 65: 156.3}
    reverses_at_hz: 27        # optional: lowest frequency where it turns from backward to forward
    peak_at_hz: 62            # optional: where it walks forward fastest
    tolerance_fraction: 0.3   # optional: each speed within ± 30 % (default; at least 30 % of 20 mm/s)
    tolerance_hz: 2           # optional: each landmark within ± 2 Hz (default)

At least a speed or a landmark is needed. The landmarks are the curve's shape
(:func:`beambench.analysis.walking.speed_curve_shape`); a targets file adds a 2 Hz grid ± 8 Hz around each to the
frequencies the calibrator runs, a walker session's own curve gives both (where it has them) on its own steps.

The tolerances decide the calibration's per-target verdict (:mod:`.verdict`), not the objective.
Either source becomes a :class:`Targets`: a per-step *target map* (frequency → regime label and, where measured,
contacts per cycle and in-contact fraction) plus the scalar targets it came from, so the objective compares
per-frequency vectors whatever the source.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from beambench.common.errors import BeambenchError
from beambench.common.inputs import read_input_bytes
from beambench.common.yaml_config import ConfigError, parse_yaml
from beambench.sim.scenes.contact_regimes import CONTINUOUS, transitions

__all__ = [
    "CalibrationInputError",
    "Targets",
    "contact_session_targets",
    "contact_targets",
    "open_session",
    "read_targets_file",
    "target_map",
    "targets_rig",
    "walker_session_targets",
    "walker_targets",
]
THIRD_SPAN_HZ = 4.0  # a targets file says nothing above third_at_hz + this: the ⅓ band's width is unknown


TARGETS_MAX_BYTES = 1 << 20  # a targets file is a few kB: kind and size are checked before it is read


class CalibrationInputError(BeambenchError, ValueError):
    """Bad input to the calibrator (file, rig, contradicting targets); ``str()`` is one line."""


@dataclass
class Targets:
    """What to reproduce. ``table``: one row per target step, columns ``frequency_hz``, ``regime`` and
    optionally ``contacts_per_cycle``, ``in_contact_fraction``, ``tangential_sign``, ``tip_major_mm``,
    ``tip_minor_mm`` (NaN where unknown). ``scalars``: the transitions (Hz) and other rig-specific targets.
    ``protocol_text``: the session's protocol (None for a targets file); ``prior``: the session's parameter set
    (name or path) and gap, used as the centre of the search."""

    rig: str
    source: str
    table: pd.DataFrame
    scalars: dict[str, Any] = field(default_factory=dict)
    protocol_text: str | None = None
    prior: dict[str, Any] = field(default_factory=dict)
    tolerance: dict[str, float] = field(default_factory=dict)  # the file's tolerance_hz / tolerance_fraction

    @property
    def frequencies(self) -> np.ndarray:
        return self.table["frequency_hz"].to_numpy(float)


# --------------------------------------------------------------------------------------------- targets file


def _number(where: str, key: str, value: Any) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise CalibrationInputError(f"{where}: {key} = {value!r}: expected a number") from None
    if not math.isfinite(x) or x <= 0:
        raise CalibrationInputError(f"{where}: {key} = {value!r}: expected a frequency > 0 Hz")
    return x


def _freq_map(where: str, key: str, value: Any, signs: bool = False) -> dict[float, float]:
    if not isinstance(value, dict) or not value:
        raise CalibrationInputError(f"{where}: {key}: expected a mapping of frequency (Hz) to a value")
    out: dict[float, float] = {}
    for f, v in value.items():
        hz = _number(where, f"{key}.{f}", f)
        try:
            x = float(v)
        except (TypeError, ValueError):
            raise CalibrationInputError(f"{where}: {key}.{f} = {v!r}: expected a number") from None
        if signs and x not in (-1.0, 1.0):
            raise CalibrationInputError(f"{where}: {key}.{f} = {v!r}: expected -1 or 1")
        out[hz] = x
    return out


CONTACT_KEYS = (
    "rig",
    "continuous_below_hz",
    "half_at_hz",
    "third_at_hz",
    "tangential_sign",
    "tolerance_hz",
    "name",
    "description",
)


def _tolerance(where: str, data: dict[str, Any], key: str) -> dict[str, float]:
    """``{key: value}`` of an optional tolerance (a number > 0), else ``{}``."""
    if key not in data:
        return {}
    try:
        x = float(data[key])
    except (TypeError, ValueError):
        raise CalibrationInputError(f"{where}: {key} = {data[key]!r}: expected a number") from None
    if not math.isfinite(x) or x <= 0:
        raise CalibrationInputError(f"{where}: {key} = {data[key]!r}: expected a tolerance > 0")
    return {key: x}


def targets_rig(data: Any, where: str) -> str:
    """The rig a targets mapping is for (its ``rig:`` field; :func:`~.rig.parse_targets` hands the mapping to that
    rig's reader); one line when the mapping or the field is missing."""
    if not isinstance(data, dict):
        raise CalibrationInputError(f"{where}: expected a mapping with a rig: field")
    rig = data.get("rig")
    if rig is None:
        raise CalibrationInputError(f"{where}: rig: missing (the rig the targets are for)")
    return str(rig)


WALKER_LANDMARKS = ("reverses_at_hz", "peak_at_hz")  # beambench.analysis.walking.SpeedCurveShape's fields
WALKER_KEYS = ("rig", "speed_mm_s", *WALKER_LANDMARKS, "tolerance_fraction", "tolerance_hz", "name", "description")
LANDMARK_GRID_HZ = 2.0  # a landmark from a targets file is measured on this grid ...
LANDMARK_SPAN_HZ = 8.0  # ... over ± this around the target


def walker_targets(data: dict[str, Any], where: str) -> Targets:
    """A walker's targets file (module docstring): speeds at frequencies and the curve's landmarks."""
    unknown = set(data) - set(WALKER_KEYS)
    if unknown:
        raise CalibrationInputError(f"{where}: {sorted(unknown)[0]}: unknown field for rig: walker")
    speeds = _freq_map(where, "speed_mm_s", data["speed_mm_s"]) if data.get("speed_mm_s") is not None else {}
    landmarks = {k: _number(where, k, data[k]) for k in WALKER_LANDMARKS if data.get(k) is not None}
    if not speeds and not landmarks:
        raise CalibrationInputError(f"{where}: speed_mm_s: missing (or give reverses_at_hz / peak_at_hz)")
    grid = {
        float(f)
        for hz in landmarks.values()
        for f in np.round(hz + np.arange(-LANDMARK_SPAN_HZ, LANDMARK_SPAN_HZ + 1e-9, LANDMARK_GRID_HZ))
        if f >= 1.0
    }
    tol = {**_tolerance(where, data, "tolerance_fraction"), **_tolerance(where, data, "tolerance_hz")}
    return _walker(where, speeds, landmarks, sorted(set(speeds) | grid), tolerance=tol)


def _walker(
    where: str,
    speeds: dict[float, float],
    landmarks: dict[str, float],
    frequencies: list[float],
    protocol_text: str | None = None,
    tolerance: dict[str, float] | None = None,
) -> Targets:
    table = pd.DataFrame(
        {"frequency_hz": frequencies, "body_speed_mm_s": [speeds.get(f, math.nan) for f in frequencies]}
    )
    table["regime"] = ""
    scalars: dict[str, Any] = {"speed_mm_s": speeds, **landmarks}
    return Targets("walker", where, table, scalars, protocol_text, tolerance=tolerance or {})


def contact_targets(data: dict[str, Any], where: str) -> Targets:
    unknown = set(data) - set(CONTACT_KEYS)
    if unknown:
        raise CalibrationInputError(f"{where}: {sorted(unknown)[0]}: unknown field for rig: contact")
    cont = _number(where, "continuous_below_hz", data["continuous_below_hz"]) if "continuous_below_hz" in data else None
    half = _number(where, "half_at_hz", data["half_at_hz"]) if "half_at_hz" in data else None
    third = _number(where, "third_at_hz", data["third_at_hz"]) if "third_at_hz" in data else None
    if cont is None and half is None and third is None:
        raise CalibrationInputError(f"{where}: needs at least one of continuous_below_hz, half_at_hz, third_at_hz")
    if half is not None and third is not None and half >= third:
        raise CalibrationInputError(
            f"{where}: half_at_hz = {half:g} is not below third_at_hz = {third:g} (½ comes before ⅓ as f rises)"
        )
    for name, hi in (("half_at_hz", half), ("third_at_hz", third)):
        if cont is not None and hi is not None and cont > hi:
            raise CalibrationInputError(
                f"{where}: continuous_below_hz = {cont:g} is above {name} = {hi:g} (the foot cannot stay down there)"
            )
    signs = (
        _freq_map(where, "tangential_sign", data["tangential_sign"], signs=True) if "tangential_sign" in data else {}
    )
    scalars = {"continuous_below_hz": cont, "half_at_hz": half, "third_at_hz": third, "tangential_sign": signs}
    table = target_map(scalars)
    return Targets("contact", where, table, scalars, tolerance=_tolerance(where, data, "tolerance_hz"))


def target_map(scalars: dict[str, Any], step_hz: float = 1.0) -> pd.DataFrame:
    """The per-step regimes the transitions imply, every ``step_hz`` from 1 Hz to ⅓ + 4 Hz (or ½ + 8, or the
    continuous edge + 8): continuous below the edge, then 1 (one contact per cycle), ½ from half_at_hz, ⅓ from
    third_at_hz. Where a transition is not given its band is left out (regime "" = no constraint)."""
    cont, half, third = (scalars.get(k) for k in ("continuous_below_hz", "half_at_hz", "third_at_hz"))
    top = third + THIRD_SPAN_HZ if third else (half + 8.0 if half else float(cont or 0.0) + 8.0)
    freqs = np.arange(1.0, math.floor(top) + 1e-9, step_hz)
    labels = []
    for f in freqs:
        if third is not None and f >= third:
            lab = "1/3"
        elif half is not None and f >= half:
            lab = "1/2"
        elif cont is not None and f < cont:
            lab = CONTINUOUS
        elif cont is not None or half is not None:
            # between the edge and ½ the foot bounces once a cycle; with no edge given, only just below ½
            lab = "1" if (cont is not None or (half is not None and f >= half - 4.0)) else ""
        else:
            lab = ""
        labels.append(lab)
    t = pd.DataFrame({"frequency_hz": freqs, "regime": labels})
    signs = scalars.get("tangential_sign") or {}
    t["tangential_sign"] = [signs.get(float(f), np.nan) for f in freqs]
    extra = [f for f in signs if not np.isclose(freqs, f).any()]
    if extra:
        t = pd.concat(
            [
                t,
                pd.DataFrame(
                    {"frequency_hz": extra, "regime": [""] * len(extra), "tangential_sign": [signs[f] for f in extra]}
                ),
            ]
        ).sort_values("frequency_hz", ignore_index=True)
    return t[t["regime"].ne("") | t["tangential_sign"].notna()].reset_index(drop=True)


def read_targets_file(path: str | Path) -> Any:
    """A targets YAML file's contents (kind and size checked first; one line on any problem)."""
    p = Path(path)
    text = read_input_bytes(p, "targets file", TARGETS_MAX_BYTES, CalibrationInputError).decode("utf-8", "replace")
    try:
        return parse_yaml(text, str(p))  # the project's one YAML reading: caps, duplicate keys refused
    except ConfigError as exc:
        raise CalibrationInputError(str(exc)) from None
    except OSError as exc:
        raise CalibrationInputError(f"{p}: {exc.strerror or exc}") from None


# --------------------------------------------------------------------------------------------- session


def open_session(path: str | Path) -> tuple[Path, Any, dict[str, Any]]:
    """A session file to take targets from: its path, the session and its ``/general`` (one line if unreadable)."""
    from beambench.sinks.session_file.reader import SessionFileError, read_session

    p = Path(path)
    if not p.is_file():
        raise CalibrationInputError(f"{p}: no such session file")
    try:
        session = read_session(p)
    except SessionFileError as exc:  # already one line naming the file
        raise CalibrationInputError(str(exc)) from None
    except (OSError, KeyError) as exc:
        raise CalibrationInputError(f"{p}: not a beambench session file ({exc})") from None
    return p, session, dict(session.general)


def contact_session_targets(p: Path, session: Any, general: dict[str, Any]) -> Targets:
    """Per-step targets of a measured (or twin-made) contact session, analysed with
    :mod:`beambench.analysis.session_analysis`; the release-test fit it holds (``/processing/fit``) or the parameter
    set it ran with is the prior."""
    from beambench.analysis.session_analysis import analyze_session

    if "loadcell" not in session.streams or len(session.streams["loadcell"].host_time_ns) == 0:
        raise CalibrationInputError(f"{p}: no load-cell data: the contact calibration needs the normal force")
    if len(session.steps) == 0:
        raise CalibrationInputError(f"{p}: the session has no steps")
    try:
        analysis = analyze_session(session)
    except (ValueError, KeyError, IndexError) as exc:
        raise CalibrationInputError(f"{p}: cannot analyse this session ({type(exc).__name__}: {exc})") from None
    t = analysis.table
    if "regime" not in t or not t["regime"].astype(str).ne("").any():
        raise CalibrationInputError(f"{p}: no contact data in any step (no normal force in the record windows)")
    keep = [
        c
        for c in (
            "frequency_hz",
            "regime",
            "contacts_per_cycle",
            "in_contact_fraction",
            "tangential_sign",
            "tip_major_mm",
            "tip_minor_mm",
        )
        if c in t
    ]
    table = t[keep].copy()
    table = table[table["regime"].astype(str).ne("")].reset_index(drop=True)
    if "tangential_sign" in table:
        table["tangential_sign"] = table["tangential_sign"].where(table["tangential_sign"].ne(0))
    scalars: dict[str, Any] = dict(transitions(table["frequency_hz"].to_numpy(float), list(table["regime"])))
    proto = yaml.safe_load(str(general.get("protocol", ""))) or {}
    sim = proto.get("sim", {}) if isinstance(proto, dict) else {}
    prior: dict[str, Any] = {"params": str(sim.get("params", "paper")), "model": str(sim.get("model", "prb3"))}
    if "plate_gap_m" in general:
        prior["gap_mm"] = float(general["plate_gap_m"]) * 1e3
    fit = _release_fit(p)
    if fit:
        prior["release_fit"] = fit
    return Targets("contact", str(p), table, scalars, str(general.get("protocol", "")) or None, prior)


def _release_fit(path: Path) -> dict[str, float]:
    """k, b (and whatever scalars) of a release-test fit stored under ``/processing/fit``, if any."""
    import h5py

    try:
        with h5py.File(path, "r", libver="latest", swmr=True) as f:
            g = f.get("processing/fit")
            if g is None:
                return {}
            out = {}
            for k, v in g.items():
                if hasattr(v, "shape") and v.shape in ((), (1,)) and np.issubdtype(v.dtype, np.number):
                    out[k] = float(np.asarray(v[()]).reshape(-1)[0])
            return out
    except OSError:
        return {}


def walker_session_targets(p: Path, session: Any, general: dict[str, Any]) -> Targets:
    """The speeds and speed-curve landmarks of a measured (or twin-made) walker session."""
    from beambench.analysis.session_analysis import analyze_session

    analysis = analyze_session(session)
    t = analysis.table
    if "body_speed_mm_s" not in t or not t["body_speed_mm_s"].notna().any():
        raise CalibrationInputError(f"{p}: no body speed in any step: is the body marker tracked?")
    from beambench.analysis.walking import speed_curve_shape

    table = t[["frequency_hz", "body_speed_mm_s"]].dropna().reset_index(drop=True)
    speeds = dict(zip(table["frequency_hz"].astype(float), table["body_speed_mm_s"].astype(float)))
    shape = speed_curve_shape(table["frequency_hz"].to_numpy(float), table["body_speed_mm_s"].to_numpy(float))
    landmarks = {k: float(v) for k in WALKER_LANDMARKS if (v := getattr(shape, k)) is not None}
    return _walker(str(p), speeds, landmarks, sorted(speeds), str(general.get("protocol", "")) or None)
