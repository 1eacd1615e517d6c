"""What the calibrator knows of a rig (:class:`CalibratableRig`), the fixed part of its twin
(:class:`CalibrationBase`) and the registry the rig modules register themselves in (:func:`register_rig`).

A rig module (``contact.py``, ``walker.py``) registers the function that makes its :class:`CalibratableRig` with
``@register_rig``; the package imports every rig module by name, so ``get_rig(name)`` finds them — no module is
loaded by a name string.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from beambench.common.registry import Registry
from beambench.sim.settings import SimSettings
from beambench.studies.twin_calibration.checks import TargetCheck
from beambench.studies.twin_calibration.targets import (
    CalibrationInputError,
    Targets,
    open_session,
    read_targets_file,
    targets_rig,
)
from beambench.studies.unknowns import Unknown

__all__ = [
    "RIGS",
    "CalibratableRig",
    "CalibrationBase",
    "Landmarks",
    "get_rig",
    "load_targets",
    "parse_targets",
    "register_rig",
    "session_targets",
    "unknowns_help",
]


@dataclass(frozen=True)
class CalibrationBase:
    """The fixed part of a twin, sent with every evaluation to the workers (frozen, picklable, hashed into the
    evaluation log's keys): the beam model, the prior parameter set (name or path), the simulation settings of
    the protocol the calibration writes (twist, amplitude, integrator, its windows, noise and seed), that
    protocol's sweep (empty: the rig has no verify stage) and the tolerance its timestep plan is chosen for."""

    model: str
    params: str
    sim: SimSettings = field(default_factory=SimSettings)
    frequencies: tuple[float, ...] = ()
    tolerance_mm: float = 0.1  # the accuracy the run's measured timestep plan is chosen for (sim.tolerance_mm)


# landmarks(steps, targets) -> {name: (the map's value or None where it has none, the target's value)}, both in
# the units the objective compares them in (the contact rig: Hz; the landmark steps move them to the targets')
Landmarks = Callable[[pd.DataFrame, Targets], dict[str, tuple[float | None, float]]]
Steps = dict[str, Any]  # {"steps": [row per frequency], "extras": {...}} (JSON-friendly: the log is JSON lines)


@dataclass(frozen=True)
class CalibratableRig:
    """A rig the calibrator can fit.

    - ``unknowns``: the fitted parameters with their bounds and effects; those with ``fitted_by_default`` (and
      not ``opt_in``) are fitted unless the caller names others (:attr:`default_free`);
    - ``simulate(base, values, frequencies, sim) -> {"steps": [...], "extras": {...}}``: a picklable
      module-level function (it runs in executor workers);
    - ``objective(steps, targets) -> (J, {term: value})``; ``base(targets) -> CalibrationBase``;
    - ``write(base, values, extras, targets, out_dir, name) -> Path``: the calibrated protocol;
    - ``summary(steps) -> dict`` for the report (transitions, speeds …);
    - ``bracket``: the unknown refined last with a 1-D search (or None);
    - ``stage_sim(stage, sim) -> sim``: the rig's own simulation settings per stage instead of the search's
      windows (the walker's speed needs a longer settle and a timestep per stage);
    - ``verify(base) -> (frequencies, sim)``: how the written protocol runs — the best candidates are re-run so
      before the winner is chosen (None: no verify stage);
    - ``run_written(path, seed) -> steps``: run a written protocol as the user will (``beambench run`` then
      ``analyze``); the verify stage then judges the candidates on those maps;
    - ``prior(base) -> {name: value}``: the prior parameter set's own values of the unknowns, the centre of the
      search's first line (None: 1 for log unknowns whose bounds hold it, else their defaults);
    - ``landmarks``: the map's landmarks the targets name (trust-region steps after the lines; None: none);
    - ``checks(targets) -> [TargetCheck]``: each target with its tolerance, for the verdict after the search
      (:mod:`.verdict`; None: no verdict, the command cannot say whether a target was met);
    - ``boxes(base) -> {name: (lo, hi)}``: the prior set's physical ranges (its ``bounds:`` block) as the
      unknowns' boxes, in the unknowns' own units; they replace the unknowns' generic boxes (which stay for
      sets without bounds: the documented effective sets), so the search never leaves a physical range;
    - ``file_targets(data, where) -> Targets``: its targets file's mapping read (``--targets``; None: it takes none);
    - ``session_targets(path, session, general) -> Targets``: its session's targets (``--session``; None: none);
    - ``cpu_per_sim_s(base, sim) -> float``: an evaluation's measured CPU seconds per simulated second on one idle
      core, the search's budget clock (:class:`.evaluate.BudgetClock`; None: a default);
    - ``quick``: the rig's own ``--quick`` search settings, (name, value) pairs that override
      ``SearchSettings.quick()``'s (the contact rig's verify stage runs the written protocol: its quick search
      plans its budget around it).
    """

    name: str
    unknowns: tuple[Unknown, ...]
    simulate: Callable[[CalibrationBase, dict[str, float], list[float], SimSettings], Steps]
    objective: Callable[[pd.DataFrame, Targets], tuple[float, dict[str, float]]]
    base: Callable[[Targets], CalibrationBase]
    write: Callable[..., Path]
    summary: Callable[[pd.DataFrame], dict]
    bracket: str | None = None
    min_frequency_hz: float = 3.0
    stage_sim: Callable[[str, SimSettings], SimSettings] | None = None
    verify: Callable[[CalibrationBase], tuple[list[float], SimSettings]] | None = None
    run_written: Callable[[Path, int | None], Steps] | None = None
    prior: Callable[[CalibrationBase], dict[str, float]] | None = None
    landmarks: Landmarks | None = None
    checks: Callable[[Targets], list[TargetCheck]] | None = None
    boxes: Callable[[CalibrationBase], dict[str, tuple[float, float]]] | None = None
    quick: tuple[tuple[str, Any], ...] = ()
    file_targets: Callable[[dict[str, Any], str], Targets] | None = None
    session_targets: Callable[[Path, Any, dict[str, Any]], Targets] | None = None
    cpu_per_sim_s: Callable[[CalibrationBase, SimSettings], float] | None = None

    @property
    def default_free(self) -> tuple[str, ...]:
        """The unknowns fitted unless the caller names others, in their declared order."""
        return tuple(u.name for u in self.unknowns if u.fitted_by_default and not u.opt_in)


def stepping_cost(scene: str, model: str, sim: SimSettings, own_dt: float, fallback: float) -> float:
    """CPU seconds per simulated second of ``scene`` on one idle core (a rig's ``cpu_per_sim_s``): its measured
    stepping cost at its own timestep ``own_dt`` (``sim_backend/step_costs.csv``, mean over the drive frequencies;
    ``fallback`` where no row holds ``model``), scaled to a fixed ``sim.timestep``."""
    measured = _measured_cost(scene, model, sim.integrator or "implicitfast")
    cost = fallback if measured is None else measured
    if sim.timestep is not None:
        dt = sim.timestep if isinstance(sim.timestep, float | int) else min(sim.timestep)
        cost *= own_dt / float(dt)
    return cost


@functools.cache
def _measured_cost(scene: str, model: str, integrator: str) -> float | None:
    """The mean measured cost of ``scene`` at its own timestep (None: no row), read once: the search's clock asks
    for it at every batch and every stop test."""
    from beambench.session.estimate import read_costs

    key = (scene, model, integrator, "auto")
    rows = [
        float(r["cpu_s_per_sim_s"])
        for r in read_costs()
        if (r["scene"], r["model"], r["integrator"], r["timestep"]) == key
    ]
    return sum(rows) / len(rows) if rows else None


RIGS: Registry[CalibratableRig] = Registry("calibratable rig")
"""Every calibratable rig by name, in registration order."""


def register_rig(make: Callable[[], CalibratableRig]) -> Callable[[], CalibratableRig]:
    """Register the rig the decorated function makes (a rig module's ``@register_rig``, as dm_control's
    ``@SUITE.add``); a second rig of the same name is refused."""
    rig = make()
    RIGS.add(rig.name, rig)
    return make


def unknowns_help() -> str:
    """Every registered rig's unknowns in words, for ``calibrate sim --free``'s help: those fitted by default,
    then the others (one registry: the help cannot drift from what the search fits)."""
    parts = []
    for rig in RIGS.values():
        others = [u.name for u in rig.unknowns if u.name not in rig.default_free]
        also = f"; also {', '.join(others)}" if others else ""
        parts.append(f"{rig.name} rig: {', '.join(rig.default_free)} by default{also}")
    return "; ".join(parts)


def get_rig(name: str) -> CalibratableRig:
    """The registered rig ``name``; CalibrationInputError (one line) for a rig the calibrator does not know."""
    if name not in RIGS:
        raise CalibrationInputError(
            f"rig: {name}: the calibrator does not know this rig yet (calibratable: {', '.join(sorted(RIGS))})"
        )
    return RIGS[name]


def _calibratable(rig: str, where: str) -> CalibratableRig:
    if rig not in RIGS:
        known = " or ".join(RIGS)
        raise CalibrationInputError(f"{where}: rig = {rig!r}: unknown rig for the calibrator ({known})")
    return RIGS[rig]


def parse_targets(data: Any, where: str = "<targets>") -> Targets:
    """A targets mapping read by the reader its ``rig:`` registered (:attr:`CalibratableRig.file_targets`)."""
    rig = _calibratable(targets_rig(data, where), where)
    if rig.file_targets is None:
        raise CalibrationInputError(f"{where}: rig = {rig.name!r}: the calibrator takes no targets file for it")
    return rig.file_targets(data, where)


def load_targets(path: str | Path) -> Targets:
    """Read a targets YAML file (``calibrate sim --targets``)."""
    return parse_targets(read_targets_file(path), str(path))


def session_targets(path: str | Path) -> Targets:
    """The targets of a measured (or twin-made) session, read by the reader its rig registered
    (:attr:`CalibratableRig.session_targets`; the rig recorded in the session, as the analysis reads it)."""
    from beambench.analysis.session_analysis import session_rig

    p, session, general = open_session(path)
    rig = _calibratable(session_rig(general), str(p))
    if rig.session_targets is None:
        raise CalibrationInputError(f"{p}: rig = {rig.name!r}: the calibrator takes no session of this rig")
    return rig.session_targets(p, session, general)
