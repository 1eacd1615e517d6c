"""Named beam parameter sets, loaded from ``sim_backend/<model>_<name>.yaml`` (SI units throughout).

A parameter set describes one beam model (``prb3`` today; ``rod`` or fitted sets later): its geometry,
stiffness, damping and mass, plus optional rig overrides (foot, contact) that a fit may have changed.
Drop a new ``sim_backend/prb3_<name>.yaml`` and select it with ``sim.params: <name>`` in a protocol.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from beambench.common.resources import shipped_dir

SIM_BACKEND_DIR = shipped_dir("sim_backend")


class ParamsError(ValueError):
    """A parameter set is missing or malformed (one-line message naming the file and the field)."""


@dataclass(frozen=True)
class Material:
    """Isotropic material of the printed beam (used by continuum and segmented models)."""

    youngs_modulus: float = 26e6  # Pa (TPU 95A datasheet)
    poisson: float = 0.45
    density: float = 1210.0  # kg/m^3


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
    material: Material = field(default_factory=Material)
    rig: dict[str, Any] = field(default_factory=dict)  # optional overrides of rig parameters (foot, contact)

    @property
    def length(self) -> float:
        return self.l1 + self.l2 + self.l3

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def available(model: str = "prb3") -> list[str]:
    """Names of the parameter sets shipped for ``model``."""
    return sorted(p.stem.removeprefix(f"{model}_") for p in SIM_BACKEND_DIR.glob(f"{model}_*.yaml"))


def has_params(name: str, model: str) -> bool:
    """Whether ``name`` (a set name or a YAML path) gives parameters for the model family ``model``."""
    path = Path(name)
    if path.suffix in (".yaml", ".yml") and path.exists():
        try:
            data = yaml.safe_load(path.read_text()) or {}
        except yaml.YAMLError:
            return False
        return isinstance(data, dict) and str(data.get("model", "prb3")) == model
    return name in available(model)


def load_params(name: str = "paper", model: str = "prb3") -> BeamParams:
    """Load the set ``name`` (``sim_backend/<model>_<name>.yaml``) or a YAML file path."""
    path = Path(name)
    if path.suffix not in (".yaml", ".yml") or not path.exists():
        path = SIM_BACKEND_DIR / f"{model}_{name}.yaml"
    if not path.exists():
        raise ParamsError(f"sim.params = {name!r}: no parameter set {path.name} (available: {available(model)})")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ParamsError(f"{path}: not valid YAML ({exc})") from None
    return params_from_dict(data, str(path))


def params_from_dict(data: dict[str, Any], where: str = "<params>") -> BeamParams:
    """Build :class:`BeamParams` from a mapping with a ``beam`` block (and optional ``rig`` block)."""
    beam = dict(data.get("beam") or {})
    known = {f.name for f in fields(BeamParams)}
    mat = beam.pop("material", None) or {}
    unknown = set(beam) - known
    if unknown:
        raise ParamsError(f"{where}: beam.{sorted(unknown)[0]}: unknown field")
    try:
        material = Material(**{k: float(v) for k, v in mat.items()})
        values = {k: float(v) for k, v in beam.items()}
    except (TypeError, ValueError) as exc:
        raise ParamsError(f"{where}: {exc}") from None
    for key in ("l2", "l3", "k", "b", "mass", "width", "thickness", "beta"):
        if key in values and values[key] <= 0:
            raise ParamsError(f"{where}: beam.{key} = {values[key]}: must be > 0")
    return BeamParams(
        name=str(data.get("name", Path(where).stem)),
        model=str(data.get("model", "prb3")),
        source=str(data.get("source", "")),
        material=material,
        rig=dict(data.get("rig") or {}),
        **values,
    )
