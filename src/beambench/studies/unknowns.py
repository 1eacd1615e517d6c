"""The parameters a study varies, with their physical bounds, and how a value of one goes into a parameter set.

One idea for every study: a calibration's unknowns (:mod:`beambench.studies.twin_calibration`), a release fit's
variables (:mod:`beambench.studies.fit.release`) and a sweep's per-point overrides (:mod:`beambench.studies.sweep.run`) are
each an :class:`Unknown` — a name, the box ``[lo, hi]`` the value may take (the search never leaves it), a log or
linear search axis — whose :meth:`Unknown.apply` puts a value into a :class:`BeamParams`. The usual effects are
an :class:`Override` (set or scale named fields: ``k``, ``material.youngs_modulus``, ``rig.frame_mass``);
:data:`BEAM_OVERRIDES` are the beam's own (stiffness, damping, lengths, modulus) shared by the fit and the sweep.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from beambench.sim.models.params import BeamParams

Effect = Callable[["BeamParams", float], "BeamParams"]  # (parameter set, value) -> the set with the value in it


@dataclass(frozen=True)
class Override:
    """Sets ``fields`` of a :class:`BeamParams` to ``value × si`` — or, with ``scale``, multiplies them by the
    value and divides the ``inverse`` fields by it. A field is an attribute (``k``), a nested one
    (``material.youngs_modulus``) or a key of the rig block (``rig.frame_mass``; scaling one needs the key in
    the block — the scene's default is the scene's to know, e.g. ``contact.scale_friction``) or of the walker's
    (``walker.foot_mass``: the set's walker block, else its rig block, as the walker scene reads them)."""

    fields: tuple[str, ...]
    scale: bool = False
    si: float = 1.0
    inverse: tuple[str, ...] = ()

    def __call__(self, params: BeamParams, value: float) -> BeamParams:
        v = value * self.si if self.si != 1.0 else value
        for path in self.fields:
            params = _set(params, path, (lambda old: old * v) if self.scale else (lambda old: v), self.scale)
        if v != 0:
            for path in self.inverse:
                params = _set(params, path, lambda old: old / v, True)
        return params


def _set(params: BeamParams, path: str, new: Callable[[float], float], reads: bool) -> BeamParams:
    """``params`` with the field at ``path`` set to ``new(old value)`` (``reads``: ``new`` needs the old one)."""
    from beambench.sim.models.params import OVERRIDE_BLOCKS

    head, _, rest = path.partition(".")
    changes: dict[str, Any]
    if head in OVERRIDE_BLOCKS:
        # walker.x: the block the walker scene reads — the set's walker block where it has one (the physical set,
        # whose rig block is the contact rig's), else its rig block (the first, which every scene reads)
        block = head if getattr(params, head) else OVERRIDE_BLOCKS[0]
        values = getattr(params, block)
        if reads and rest not in values:
            raise ValueError(f"{path}: the parameter set's {block} block has no {rest} to scale (use a function)")
        changes = {block: {**values, rest: new(values.get(rest, math.nan))}}
    elif rest:
        inner = getattr(params, head)
        changes = {head: replace(inner, **{rest: new(getattr(inner, rest))})}
    else:
        changes = {head: new(getattr(params, head))}
    return replace(params, **changes)


@dataclass(frozen=True)
class Unknown:
    """One varied parameter: physical bounds ``[lo, hi]`` (the search works on ``log10(value)`` for ``log=True``,
    else on the value, and never leaves them) and how a value goes into a parameter set (``effect``; None: it
    does not — e.g. the contact rig's preload, which sets the gap). For a calibration also: the value when not
    fitted (``default``; None: the middle of the bounds), the prior parameter set's own value (``own``; the
    centre of the search's first line), whether it is fitted unless the caller names others
    (``fitted_by_default``) and whether it is fitted only when named (``opt_in``: when not fitted the prior's
    own value stays, not ``default``)."""

    name: str
    lo: float
    hi: float
    log: bool = False
    unit: str = ""
    doc: str = ""
    default: float | None = None
    opt_in: bool = False
    effect: Effect | None = None
    own: Callable[[BeamParams], float] | None = None
    fitted_by_default: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lo) and math.isfinite(self.hi) and self.lo < self.hi):
            raise ValueError(f"unknown {self.name}: bounds [{self.lo}, {self.hi}] are not a finite interval")
        if self.log and self.lo <= 0:
            raise ValueError(f"unknown {self.name}: a log axis needs lo > 0 (got {self.lo})")
        if self.default is not None and not self.lo <= self.default <= self.hi:
            raise ValueError(f"unknown {self.name}: default {self.default:g} outside [{self.lo:g}, {self.hi:g}]")

    @property
    def bounds(self) -> tuple[float, float]:
        """The bounds on the search axis."""
        return (math.log10(self.lo), math.log10(self.hi)) if self.log else (self.lo, self.hi)

    def value(self, u: float) -> float:
        """The value at search coordinate ``u``."""
        return float(10.0**u) if self.log else float(u)

    def coord(self, value: float) -> float:
        """The search coordinate of ``value``."""
        return math.log10(value) if self.log else float(value)

    def within(self, lo: float, hi: float) -> Unknown:
        """The same unknown searched over ``[lo, hi]``, which must lie inside its bounds."""
        if not (self.lo <= lo < hi <= self.hi):
            raise ValueError(f"{self.name}: [{lo:g}, {hi:g}] is not inside its bounds [{self.lo:g}, {self.hi:g}]")
        return replace(self, lo=lo, hi=hi)

    def apply(self, params: BeamParams, value: float) -> BeamParams:
        """``params`` with ``value`` of this unknown in it (unchanged if it has no effect on a parameter set)."""
        return self.effect(params, value) if self.effect is not None else params


def apply_values(params: BeamParams, unknowns: Iterable[Unknown], values: Mapping[str, float | None]) -> BeamParams:
    """``params`` with every value of ``values`` (None: not set) applied, in the order of ``unknowns``."""
    for u in unknowns:
        v = values.get(u.name)
        if v is not None:
            params = u.apply(params, v)
    return params


# the beam's own parameters, as the fit and the sweep set them (PRB3: bending and twist joints alike)
BEAM_OVERRIDES: dict[str, Effect] = {
    "k": Override(("k", "k_twist")),
    "b": Override(("b", "b_twist")),
    "l1": Override(("l1",)),
    "l2": Override(("l2",)),
    "l3": Override(("l3",)),
    "youngs_modulus": Override(("material.youngs_modulus",)),
    "beta": Override(("beta",)),
}
