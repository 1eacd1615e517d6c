"""Named beam parameter sets, loaded from ``<model>_<name>.yaml`` files (SI units throughout).

A parameter set describes one beam model (``prb3`` today; ``rod`` or fitted sets later): its geometry,
stiffness, damping and mass, plus optional rig overrides (foot, contact) that a fit may have changed.
Named sets are searched in the per-user folder (where ``beambench fit`` writes) and then in the package's
``sim_backend/`` (:func:`beambench.common.resources.search_path`). Drop a new ``prb3_<name>.yaml`` in either and
select it with ``sim.params: <name>`` in a protocol.
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from beambench.common.resources import ShippedFileError, resolve_file, search_path, shipped_dir
from beambench.common.yaml_config import ConfigError, load_yaml_file, shorten

SIM_BACKEND_DIR = shipped_dir("sim_backend")  # the shipped sets and measured tables (read-only)


class ParamsError(ConfigError):
    """A parameter set is missing or malformed (one-line message naming the file and the field)."""


@dataclass(frozen=True)
class Material:
    """Isotropic material of the printed beam (used by continuum and segmented models)."""

    youngs_modulus: float = 26e6  # Pa (TPU 95A datasheet)
    poisson: float = 0.45
    density: float = 1210.0  # kg/m^3


@dataclass(frozen=True)
class Bound:
    """The physical range of one number of a parameter set (SI units) and where the range comes from."""

    min: float
    max: float
    source: str = ""

    def contains(self, value: float) -> bool:
        return self.min <= value <= self.max


@dataclass(frozen=True)
class BeamParams:
    """One beam: geometry, joint spring/damper constants and mass.

    PRB3 (paper Sec. II-B): bending joints R1, R2, R3 and twist joints R4, R5; ``l1``, ``l2``, ``l3`` are the
    distances R1–R2, R2–R3 and R3–tip. ``k``/``b`` act on the bending joints (N·m/rad, N·m·s/rad);
    ``k_twist``/``b_twist`` on the twist joints (the paper uses the same spring model for both).
    Each twist joint carries half the total twist as rest twist (90° → 45° per joint).
    Segmented-rod models use ``material``, ``width``, ``thickness``, ``mass`` and ``beta`` instead.
    """

    name: str = "paper"
    model: str = "prb3"
    source: str = ""
    l1: float = 0.0
    l2: float = 0.02366
    l3: float = 0.02634
    k: float = 0.340
    b: float = 0.0029
    k_twist: float = 0.340
    b_twist: float = 0.0029
    mass: float = 0.00517
    width: float = 0.020
    thickness: float = 0.003
    twist_deg: float = 90.0
    beta: float = 6e-4  # s, stiffness-proportional damping of continuum models (b = beta * k)
    # material loss factor (tan delta); > 0: the contact rig's hinges get the equivalent viscous damping at the
    # drive frequency, b = loss_factor * k / omega, instead of beta (beambench.sim.models.hysteretic)
    loss_factor: float = 0.0
    material: Material = field(default_factory=Material)
    rig: dict[str, Any] = field(default_factory=dict)  # optional overrides of rig parameters (foot, contact)
    # optional overrides of the walker's parameters (WalkerParams); a set without them gives the walker ``rig``
    walker: dict[str, Any] = field(default_factory=dict)
    # physical range of each number, keyed by its place in the file: ``beam.k``, ``beam.material.youngs_modulus``,
    # ``rig.friction``, ``walker.foot_mass``, and ``beam.b/k`` for a damping-to-stiffness ratio (s)
    bounds: dict[str, Bound] = field(default_factory=dict)

    @property
    def length(self) -> float:
        return self.l1 + self.l2 + self.l3

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def value(self, key: str) -> float | None:
        """The number at ``key`` (as in :attr:`bounds`: ``beam.beta``, ``beam.material.youngs_modulus``,
        ``rig.plate_gap``, ``walker.friction``, ratios ``beam.b/k``), or None where the set does not give it."""
        block, _, name = key.partition(".")
        if block in OVERRIDE_BLOCKS:
            v = getattr(self, block).get(name)
            return None if v is None else float(v)
        if block != "beam":
            return None
        if "/" in name:
            num, den = (self.value(f"beam.{n}") for n in name.split("/", 1))
            return None if num is None or not den else num / den
        if name.startswith("material."):
            return float(getattr(self.material, name.removeprefix("material."), math.nan))
        v = getattr(self, name, None)
        return float(v) if isinstance(v, (int, float)) else None

    def out_of_bounds(self) -> list[str]:
        """One line per bounded number outside its physical range (empty: every bounded number is inside)."""
        bad = []
        for key, b in self.bounds.items():
            v = self.value(key)
            if key in MODEL_OPTIONS and not v:  # an option that is off (0 or not given): its range applies when on
                continue
            if v is None:
                bad.append(f"{key}: bounded but not given")
            elif not b.contains(v):
                bad.append(f"{key} = {v:g} outside [{b.min:g}, {b.max:g}] ({b.source})")
        return bad


def available(model: str = "prb3") -> list[str]:
    """Names of the parameter sets for ``model``: the user's (fitted) and the shipped ones."""
    return sorted(
        {p.stem.removeprefix(f"{model}_") for d in search_path("sim_backend") for p in d.glob(f"{model}_*.yaml")}
    )


def find_params(name: str, model: str = "prb3") -> Path | None:
    """The file of the named set ``name`` for ``model``: the user's folder first, then the package's."""
    for folder in search_path("sim_backend"):
        if (folder / f"{model}_{name}.yaml").is_file():
            return folder / f"{model}_{name}.yaml"
    return None


def has_params(name: str, model: str) -> bool:
    """Whether ``name`` (a set name or a YAML path) gives parameters for the model family ``model``."""
    path = Path(name)
    if path.suffix in (".yaml", ".yml"):
        try:
            path = resolve_file("params", path)
        except ShippedFileError:
            return False
        try:
            data, _ = load_yaml_file(path)  # kind and size checked before the read
        except ConfigError:
            return False
        return isinstance(data, dict) and params_family(data.get("model", "prb3")) == model
    return name in available(model)


def load_params(name: str = "paper", model: str = "prb3") -> BeamParams:
    """Load the named set ``name`` (``<model>_<name>.yaml`` in :func:`find_params`' folders) or a YAML file path."""
    given = Path(name)
    if given.suffix in (".yaml", ".yml"):  # a file, or a shipped set by its path (sim_backend/prb3_paper.yaml)
        try:
            path: Path | None = resolve_file("params", given)
        except ShippedFileError as exc:
            raise ParamsError(f"sim.params = {exc}") from None
    else:
        if "/" in name or "\\" in name or "\x00" in name or len(name) > 200:
            raise ParamsError(f"sim.params = {shorten(name)}: no such parameter file")
        path = find_params(name, model)
    if path is None:
        raise ParamsError(
            f"sim.params = {shorten(name)}: no parameter set {model}_{name}.yaml (available: {available(model)})"
        )
    data, _ = load_yaml_file(path, ParamsError)
    if not isinstance(data, dict):
        raise ParamsError(f"{path}: expected a mapping with a beam block")
    says = data.get("model", "prb3")  # sets written before the field are PRB3's
    if params_family(says) != model:
        raise ParamsError(f"{path}: model: {str(says)[:20]}, not a {model} parameter set (a {model} model runs)")
    return params_from_dict(data, str(path))


def params_family(model: object) -> str:
    """The family a parameter set's ``model:`` names (``rod``, ``rod10``, ``rod3g`` → ``rod``; ``prb3``), or the
    text itself when it names none (then it matches no family)."""
    text = str(model)
    return "rod" if re.fullmatch(r"rod(\d+g?s?)?", text) else text


# bounded numbers that switch a model option on when > 0 (0 = off, the set's other numbers apply): their range
# holds only when they are on
MODEL_OPTIONS = frozenset({"beam.loss_factor", "rig.frame_gyration"})

# The physical range of each beam number (SI), whatever a set's own ``bounds:`` say: (low, high, low excluded).
# A printed beam is centimetres long and grams heavy; these are orders of magnitude around it, so a typo
# (k = 1e300, E < 0, density 0) is refused before MuJoCo turns it into NaN.
PHYSICAL: dict[str, tuple[float, float, bool, str]] = {
    "l1": (0.0, 1.0, False, "m"),
    "l2": (0.0, 1.0, True, "m"),
    "l3": (0.0, 1.0, True, "m"),
    "k": (0.0, 100.0, True, "N·m/rad"),
    "k_twist": (0.0, 100.0, True, "N·m/rad"),
    "b": (0.0, 10.0, True, "N·m·s/rad"),
    "b_twist": (0.0, 10.0, False, "N·m·s/rad"),
    "mass": (0.0, 10.0, True, "kg"),
    "width": (0.0, 1.0, True, "m"),
    "thickness": (0.0, 1.0, True, "m"),
    "twist_deg": (-720.0, 720.0, False, "deg"),
    "beta": (0.0, 1.0, True, "s"),
    "loss_factor": (0.0, 2.0, False, ""),
    "material.youngs_modulus": (1e3, 1e12, False, "Pa"),
    "material.poisson": (-1.0, 0.5, True, ""),
    "material.density": (1.0, 1e5, False, "kg/m³"),
}
# rig and walker overrides: every value a finite number of at most this magnitude; these must be > 0, and
# ``timestep`` at least MIN_OVERRIDE_TIMESTEP_S (s) as the protocol's sim.timestep
OVERRIDE_MAX = 1e6
POSITIVE_OVERRIDES = frozenset(
    {"timestep", "contact_timeconst", "contact_dampratio", "servo_hz", "sole_radius", "wheel_radius", "foot_length"}
    | {"torque_constant", "bus_voltage", "stage_armature", "stage_mass", "vel_ramp_rate", "motor_radius"}
)
NON_NEGATIVE_OVERRIDES = frozenset(
    {"foot_mass", "foot_bar_mass", "frame_mass", "sole_mass", "friction", "friction_torque", "sole_stiffness"}
    | {"sole_damping", "sole_travel", "preroll_s", "rotor_inertia"}
)
MIN_OVERRIDE_TIMESTEP_S = 1e-6
FLAG_OVERRIDES = frozenset({"sole_at_corner"})  # rig switches: true/false, not numbers
OVERRIDE_BLOCKS = ("rig", "walker")  # a set's blocks of scene-parameter overrides (the BeamParams fields of the name)
TOP_LEVEL_KEYS = frozenset({"name", "model", "source", "beam", *OVERRIDE_BLOCKS, "bounds", "fit"})


def _in_range(value: float, where: str, key: str) -> float:
    lo, hi, open_lo, unit = PHYSICAL[key]
    if value < lo or value > hi or (open_lo and value == lo):
        shown = f"{'(' if open_lo else '['}{lo:g}, {hi:g}]{' ' + unit if unit else ''}"
        raise ParamsError(f"{where}: beam.{key} = {value:g}: outside the physical range {shown}")
    return value


def _overrides(block: dict[Any, Any], where: str, name: str) -> dict[str, float]:
    """A ``rig:`` or ``walker:`` block: names to finite numbers of a physical magnitude, or to switches (a
    true/false scene option such as ``rig.sole_at_corner``; the scene checks the names)."""
    out: dict[str, float] = {}
    for key, v in block.items():
        k = str(key)
        if isinstance(v, bool):
            out[k] = v
            continue
        if k in FLAG_OVERRIDES:
            raise ParamsError(f"{where}: {name}.{k} = {shorten(v)}: must be true or false")
        value = _number(v, where, f"{name}.{k[:40]}")
        if abs(value) > OVERRIDE_MAX:
            raise ParamsError(f"{where}: {name}.{k[:40]} = {value:g}: magnitude over {OVERRIDE_MAX:g}")
        if (k in POSITIVE_OVERRIDES and value <= 0) or (k in NON_NEGATIVE_OVERRIDES and value < 0):
            raise ParamsError(f"{where}: {name}.{k} = {value:g}: must be {'>' if k in POSITIVE_OVERRIDES else '>='} 0")
        if k == "timestep" and value < MIN_OVERRIDE_TIMESTEP_S:
            raise ParamsError(f"{where}: {name}.timestep = {value:g}: at least {MIN_OVERRIDE_TIMESTEP_S:g} s")
        out[k] = value
    return out


def _number(value: Any, where: str, key: str) -> float:
    """A finite number (not a bool, not a string), else :class:`ParamsError`."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParamsError(f"{where}: {key} = {shorten(value)}: must be a number")
    if not math.isfinite(value):
        raise ParamsError(f"{where}: {key} = {value}: must be a finite number")
    return float(value)


def params_from_dict(data: dict[str, Any], where: str = "<params>") -> BeamParams:
    """Build :class:`BeamParams` from a mapping with a ``beam`` block (and optional ``rig`` block)."""
    unknown_top = sorted(map(str, set(data) - TOP_LEVEL_KEYS))
    if unknown_top:
        raise ParamsError(f"{where}: {unknown_top[0][:80]}: unknown field (known: {', '.join(sorted(TOP_LEVEL_KEYS))})")
    beam_block = data.get("beam") or {}
    if not isinstance(beam_block, dict):
        raise ParamsError(f"{where}: beam: expected a mapping of beam fields")
    beam = dict(beam_block)
    known = {f.name for f in fields(BeamParams)}
    mat = beam.pop("material", None) or {}
    # a set written from ``BeamParams.to_dict()`` (e.g. a calibration's) may carry these inside its beam block
    nested_walker, nested_bounds = beam.pop("walker", None) or {}, beam.pop("bounds", None) or {}
    if not isinstance(mat, dict):
        raise ParamsError(f"{where}: beam.material: expected a mapping of material fields")
    unknown = set(beam) - (known - {"name", "model", "source", "rig", "walker", "bounds", "material"})
    if unknown:
        raise ParamsError(f"{where}: beam.{sorted(map(str, unknown))[0][:80]}: unknown field")
    unknown_mat = set(mat) - {f.name for f in fields(Material)}
    if unknown_mat:
        raise ParamsError(f"{where}: beam.material.{sorted(map(str, unknown_mat))[0][:80]}: unknown field")
    material = Material(
        **{k: _in_range(_number(v, where, f"beam.material.{k}"), where, f"material.{k}") for k, v in mat.items()}
    )
    values = {k: _in_range(_number(v, where, f"beam.{k}"), where, k) for k, v in beam.items()}
    rig = data.get("rig") or {}
    if not isinstance(rig, dict):
        raise ParamsError(f"{where}: rig: expected a mapping of rig overrides")
    walker = data.get("walker") or nested_walker
    if not isinstance(walker, dict):
        raise ParamsError(f"{where}: walker: expected a mapping of walker overrides")
    rig, walker = _overrides(rig, where, "rig"), _overrides(walker, where, "walker")
    for key in ("name", "model", "source"):
        if isinstance(data.get(key), (dict, list)):
            raise ParamsError(f"{where}: {key} = {shorten(data[key])}: must be a string")
    return BeamParams(
        name=str(data.get("name", Path(where).stem)),
        model=str(data.get("model", "prb3")),
        source=str(data.get("source", "")),
        material=material,
        rig=dict(rig),
        walker=dict(walker),
        bounds=_bounds(data.get("bounds") or nested_bounds, where),
        **values,
    )


def _bounds(block: Any, where: str) -> dict[str, Bound]:
    """The ``bounds:`` block: ``<key>: {min: .., max: .., source: ..}`` per bounded number."""
    if not isinstance(block, dict):
        raise ParamsError(f"{where}: bounds: expected a mapping of <key>: {{min, max, source}}")
    out = {}
    for key, b in block.items():
        if not isinstance(b, dict) or not {"min", "max"} <= set(b):
            raise ParamsError(f"{where}: bounds.{shorten(key)}: expected {{min: .., max: .., source: ..}}")
        lo, hi = _number(b["min"], where, f"bounds.{key}.min"), _number(b["max"], where, f"bounds.{key}.max")
        if lo > hi:
            raise ParamsError(f"{where}: bounds.{shorten(key)}: min {lo:g} > max {hi:g}")
        out[str(key)] = Bound(lo, hi, str(b.get("source", "")))
    return out
