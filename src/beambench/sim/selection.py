"""Model no more than a scene needs: pick the cheapest (model, integrator, timestep) that meets a tolerance.

The choice comes from measured tables shipped in ``sim_backend/``: ``ladder_table.csv`` for the free beam
(tip error against the 40-segment-rod reference, from ``benchmarks/bench_models.py --ship``) and
``contact_table.csv`` for the contact rig (foot-path error against the same model at a small timestep).
Each row is one configuration at one drive frequency with its error, stability status and wall time per
10 s simulated.

The timestep is chosen *per frequency* — the one that frequency needs, not the worst case over the sweep:
a configuration qualifies at frequency f if it is stable with error ≤ tolerance at the table frequencies
that bracket f — and so does every finer timestep of the same model and integrator there. Error shrinks
with the timestep in a converging method; a coarse step that passes where a finer one fails passes by a
phase coincidence (e.g. one contact bounce landing in step by chance), which a new run need not repeat.
The exception is a frequency whose regime the table marks ``irregular`` (no timestep converges it
pointwise; its error is the excess over the finest runs' spread): there each timestep stands alone.
One (model, integrator) is used for a whole sweep (the cheapest summed over its frequencies); only the
timestep changes from step to step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from beambench.acquisition.protocol.scenes import SCENES, scene_or_unknown
from beambench.common.errors import BeambenchError
from beambench.common.inputs import check_input_file
from beambench.common.types import Floats
from beambench.sim.models.params import SIM_BACKEND_DIR

if TYPE_CHECKING:  # pandas loads only where a table is read: a dry run on a measured cost table needs none
    import pandas as pd

# "inaccurate" (free beam) only means > 1 % from converged, and "irregular" (contact) a regime no timestep
# converges pointwise (its error column is then the excess over the finest runs): the error column decides
STABLE = ("ok", "inaccurate", "irregular")


class SelectionError(BeambenchError, ValueError):
    """No configuration in the table meets the request (one line, names the scene and tolerance)."""


TABLE_MAX_BYTES = 16 << 20  # a measured timing table is a few hundred kB


@dataclass(frozen=True)
class Plan:
    """A model and integrator for a sweep, and the timestep for each frequency."""

    scene: str
    model: str
    integrator: str
    tolerance_mm: float
    timesteps: dict[float, float]  # frequency (Hz) → timestep (s)
    expected_err_mm: dict[float, float]  # frequency → the table's error at the bracketing frequencies (max)
    wall_s_per_10s: dict[float, float]  # frequency → measured wall time per 10 s simulated
    table: str = ""
    notes: list[str] = field(default_factory=list)

    def timestep(self, frequency_hz: float) -> float:
        """The timestep for ``frequency_hz`` (a planned frequency, or the nearest planned one above it)."""
        keys = sorted(self.timesteps)
        for f in keys:
            if abs(frequency_hz) <= f + 1e-9:
                return self.timesteps[f]
        return self.timesteps[keys[-1]]

    @property
    def total_wall_s_per_10s(self) -> float:
        return float(sum(self.wall_s_per_10s.values()))

    def describe(self) -> dict:
        """For the session's ``/general``: what was chosen, from which table, why."""
        return {
            "scene": self.scene,
            "model": self.model,
            "integrator": self.integrator,
            "tolerance_mm": self.tolerance_mm,
            "table": self.table,
            "timesteps": {f"{f:g}": dt for f, dt in sorted(self.timesteps.items())},
            "expected_err_mm": {f"{f:g}": e for f, e in sorted(self.expected_err_mm.items())},
            "notes": list(self.notes),
        }


def table_path(scene: str) -> Path:
    """The measured table of ``scene`` (its catalogue entry's ``timing_table``); one line if it has none."""
    table = scene_or_unknown(scene).timing_table
    if table is None:
        tabled = ", ".join(s.name for s in SCENES.values() if s.timing_table)
        raise SelectionError(f"scene = {scene!r}: no measured table (known: {tabled})")
    return SIM_BACKEND_DIR / table


def table_paths(scene: str) -> list[Path]:
    """Every shipped table of ``scene``: ``<table>.csv`` and per-model additions ``<table>_<model>.csv``
    (e.g. ``contact_table_rod10.csv`` from ``benchmarks/bench_models.py --part contact --model rod10 --ship``)."""
    main = table_path(scene)
    extra = sorted(main.parent.glob(f"{main.stem}_*{main.suffix}"))
    return [p for p in [main, *extra] if p.exists()]


def load_table(scene: str, path: str | Path | None = None) -> pd.DataFrame:
    """The measured table for ``scene`` — every shipped file of it, so ``sim.model: auto`` considers every
    model that has one — or the CSV at ``path``, with an ``err_mm`` column."""
    paths = [Path(path)] if path else table_paths(scene)
    if not paths or not all(p.exists() for p in paths):
        where = paths[0] if paths else table_path(scene)
        raise SelectionError(
            f"{where}: no measured table for the {scene} scene (run benchmarks/bench_models.py --ship)"
        )
    for p in paths:  # kind and size before pandas reads it
        check_input_file(p, "timing table", TABLE_MAX_BYTES, SelectionError)
    import pandas as pd

    frames = [_normalize(pd.read_csv(p), str(p)) for p in paths]
    return pd.concat(frames, ignore_index=True) if len(frames) > 1 else frames[0]


def table_models(scene: str) -> list[str]:
    """The models the shipped tables of ``scene`` cover."""
    try:
        return sorted(str(m) for m in load_table(scene).model.unique())
    except SelectionError:
        return []


def _normalize(df: pd.DataFrame, where: str = "table") -> pd.DataFrame:
    if "err_mm" not in df and "tip_err_mm" in df:
        df = df.assign(err_mm=df["tip_err_mm"])
    need = {"model", "integrator", "timestep", "frequency_hz", "status", "err_mm", "wall_s_per_10s"}
    missing = need - set(df.columns)
    if missing:
        raise SelectionError(f"{where}: missing columns {sorted(missing)}")
    if "is_reference" in df:
        df = df[~df.is_reference.astype(bool)]
    return df


def _bracket(freqs: np.ndarray, f: float) -> list[float]:
    """The table frequencies around ``f``: the two neighbours, or the nearest end."""
    f = abs(f)
    if f <= freqs[0]:
        return [float(freqs[0])]
    if f >= freqs[-1]:
        return [float(freqs[-1])]
    i = int(np.searchsorted(freqs, f))
    return [float(freqs[i])] if math.isclose(freqs[i], f) else [float(freqs[i - 1]), float(freqs[i])]


def _converged_rows(g: pd.DataFrame, tolerance_mm: float) -> dict[tuple[float, float], Any]:
    """(timestep, frequency) → row of one model/integrator that is stable within tolerance at that frequency,
    with every finer timestep in the table stable within tolerance there too (unless the regime is
    irregular there)."""
    good = g.status.isin(STABLE).to_numpy() & (g.err_mm <= tolerance_mm).to_numpy()
    irregular = g.status.to_numpy() == "irregular"
    rows = list(g.itertuples())
    out = {}
    for idx in g.groupby("frequency_hz").indices.values():
        converging = not irregular[idx].any()
        for i in sorted(idx, key=lambda i: rows[i].timestep):  # finest first
            if not good[i]:
                if converging:
                    break
                continue
            out[(rows[i].timestep, rows[i].frequency_hz)] = rows[i]
    return out


def plan_sweep(
    scene: str,
    tolerance_mm: float,
    frequencies: Floats,
    models: Sequence[str] | None = None,
    integrators: Sequence[str] | None = None,
    table: pd.DataFrame | None = None,
    table_file: str | Path | None = None,
) -> Plan:
    """The cheapest (model, integrator) and per-frequency timestep meeting ``tolerance_mm`` at every frequency.

    ``models``/``integrators`` restrict the choice (e.g. a protocol that fixes the model). Raises
    :class:`SelectionError` when nothing qualifies.
    """
    if tolerance_mm <= 0:
        raise SelectionError(f"tolerance_mm = {tolerance_mm}: must be > 0")
    df = _normalize(table) if table is not None else load_table(scene, table_file)
    if models:
        df = df[df.model.isin(models)]
    if integrators:
        df = df[df.integrator.isin(integrators)]
    freqs = np.array(sorted(df.frequency_hz.unique()), float)
    if not len(freqs):
        raise SelectionError(f"{scene}: the table has no rows for models={models} integrators={integrators}")
    wanted = sorted({abs(float(f)) for f in frequencies})
    notes = []
    if wanted and wanted[-1] > freqs[-1] + 1e-9:
        notes.append(f"{wanted[-1]:g} Hz is above the table's {freqs[-1]:g} Hz: its row is used")

    best: tuple[float, Plan] | None = None
    for (model, integ), g in df.groupby(["model", "integrator"]):
        ok = _converged_rows(g, tolerance_mm)
        if not ok:
            continue
        dts = sorted({dt for dt, _ in ok}, reverse=True)  # largest (cheapest) first
        steps, errs, walls = {}, {}, {}
        for f in wanted:
            br = _bracket(freqs, f)
            for dt in dts:
                found = [ok.get((dt, fb)) for fb in br]
                rows = [r for r in found if r is not None]
                if len(rows) == len(found):
                    steps[f] = float(dt)
                    errs[f] = float(max(r.err_mm for r in rows))
                    walls[f] = float(max(r.wall_s_per_10s for r in rows))
                    break
            else:
                break
        if len(steps) < len(wanted) or any(not np.isfinite(w) for w in walls.values()):
            continue
        cost = sum(walls.values())
        plan = Plan(
            scene,
            str(model),
            str(integ),
            float(tolerance_mm),
            steps,
            errs,
            walls,
            str(table_file or table_path(scene).name),
            notes,
        )
        if best is None or cost < best[0]:
            best = (cost, plan)
    if best is None:
        lim = f" among models {list(models)}" if models else ""
        raise SelectionError(
            f"{scene}: no measured configuration{lim} keeps the error within {tolerance_mm:g} mm "
            f"at {wanted[0]:g}–{wanted[-1]:g} Hz"
        )
    return best[1]
