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

import csv
import math
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from beambench.acquisition.protocol.scenes import SCENES, scene_or_unknown
from beambench.common.errors import BeambenchError
from beambench.common.inputs import check_input_file
from beambench.common.types import Floats
from beambench.sim.models.params import SIM_BACKEND_DIR

if TYPE_CHECKING:  # planning reads the CSV itself: a run or dry run never loads pandas for it (~0.3 s a process)
    import pandas as pd

# "inaccurate" (free beam) only means > 1 % from converged, and "irregular" (contact) a regime no timestep
# converges pointwise (its error column is then the excess over the finest runs): the error column decides
STABLE = ("ok", "inaccurate", "irregular")


class SelectionError(BeambenchError, ValueError):
    """No configuration in the table meets the request (one line, names the scene and tolerance)."""


TABLE_MAX_BYTES = 16 << 20  # a measured timing table is a few hundred kB


class TableRow(NamedTuple):
    """One configuration at one drive frequency: the columns planning reads."""

    model: str
    integrator: str
    timestep: float
    frequency_hz: float
    status: str
    err_mm: float
    wall_s_per_10s: float


COLUMNS = TableRow._fields


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


def _paths(scene: str, path: str | Path | None) -> list[Path]:
    """The table files to read, each checked (exists, a regular file, no larger than a table can be)."""
    paths = [Path(path)] if path else table_paths(scene)
    if not paths or not all(p.exists() for p in paths):
        where = paths[0] if paths else table_path(scene)
        raise SelectionError(
            f"{where}: no measured table for the {scene} scene (run benchmarks/bench_models.py --ship)"
        )
    for p in paths:  # kind and size before anything reads it
        check_input_file(p, "timing table", TABLE_MAX_BYTES, SelectionError)
    return paths


def load_table(scene: str, path: str | Path | None = None) -> pd.DataFrame:
    """The measured table for ``scene`` as a DataFrame, all its columns — every shipped file of it, or the CSV at
    ``path`` — with an ``err_mm`` column and without reference rows. Planning reads :func:`table_rows` instead."""
    import pandas as pd

    frames = [_normalize(pd.read_csv(p), str(p)) for p in _paths(scene, path)]
    return pd.concat(frames, ignore_index=True) if len(frames) > 1 else frames[0]


def table_rows(scene: str, path: str | Path | None = None) -> list[TableRow]:
    """The rows planning reads from ``scene``'s measured table (every shipped file of it, so ``sim.model: auto``
    considers every model that has one) or from the CSV at ``path``; reference rows left out."""
    return [row for p in _paths(scene, path) for row in _read_csv(p)]


def _read_csv(path: Path) -> list[TableRow]:
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        have = set(reader.fieldnames or ())
        err = _error_column(have, str(path))
        cells = ("model", "integrator", "timestep", "frequency_hz", "status", err, "wall_s_per_10s")  # TableRow's
        rows = []
        for line, rec in enumerate(reader, start=2):
            if _true(rec.get("is_reference")):
                continue
            if any(rec.get(c) is None for c in cells):
                raise SelectionError(f"{path}: line {line}: fewer cells than the header's {len(have)}")
            model, integrator, timestep, frequency, status, err_mm, wall = (str(rec[c]) for c in cells)
            try:
                rows.append(
                    TableRow(
                        model, integrator, float(timestep), float(frequency), status, _number(err_mm), _number(wall)
                    )
                )
            except ValueError as exc:  # a word where a number belongs
                raise SelectionError(f"{path}: line {line}: {exc}") from None
    return rows


def _true(cell: str | None) -> bool:
    return (cell or "").strip().lower() in ("true", "1", "1.0")


def _number(cell: str) -> float:
    """A number cell; empty is NaN (not measured), as in the tables' own writers."""
    return float(cell) if cell.strip() else math.nan


def table_models(scene: str) -> list[str]:
    """The models the shipped tables of ``scene`` cover."""
    try:
        return sorted({row.model for row in table_rows(scene)})
    except SelectionError:
        return []


def _error_column(have: set[str], where: str) -> str:
    """The column holding the error (``err_mm``, or the free beam's ``tip_err_mm``) of a table with columns ``have``;
    a table without every column planning reads is one line."""
    err = "err_mm" if "err_mm" in have else "tip_err_mm"
    missing = set(COLUMNS) - have - ({"err_mm"} if err in have else set())
    if missing:
        raise SelectionError(f"{where}: missing columns {sorted(missing)}")
    return err


def _normalize(df: pd.DataFrame, where: str = "table") -> pd.DataFrame:
    err = _error_column(set(df.columns), where)
    if err != "err_mm":
        df = df.assign(err_mm=df[err])
    if "is_reference" in df:
        df = df[~df.is_reference.astype(bool)]
    return df


def _frame_rows(df: pd.DataFrame) -> list[TableRow]:
    """A table given as a DataFrame (a study's fresh measurement) as planning rows."""
    df = _normalize(df)
    cols = [df[c].tolist() for c in COLUMNS]
    return [
        TableRow(str(m), str(i), float(dt), float(f), str(st), float(e), float(w))
        for m, i, dt, f, st, e, w in zip(*cols)
    ]


def _bracket(freqs: np.ndarray, f: float) -> list[float]:
    """The table frequencies around ``f``: the two neighbours, or the nearest end."""
    f = abs(f)
    if f <= freqs[0]:
        return [float(freqs[0])]
    if f >= freqs[-1]:
        return [float(freqs[-1])]
    i = int(np.searchsorted(freqs, f))
    return [float(freqs[i])] if math.isclose(freqs[i], f) else [float(freqs[i - 1]), float(freqs[i])]


def _converged_rows(rows: Iterable[TableRow], tolerance_mm: float) -> dict[tuple[float, float], TableRow]:
    """(timestep, frequency) → row of one model/integrator that is stable within tolerance at that frequency,
    with every finer timestep in the table stable within tolerance there too (unless the regime is
    irregular there)."""
    by_frequency: dict[float, list[TableRow]] = defaultdict(list)
    for row in rows:
        by_frequency[row.frequency_hz].append(row)
    out = {}
    for group in by_frequency.values():
        converging = not any(r.status == "irregular" for r in group)
        for r in sorted(group, key=lambda r: r.timestep):  # finest first
            if not (r.status in STABLE and r.err_mm <= tolerance_mm):
                if converging:
                    break
                continue
            out[(r.timestep, r.frequency_hz)] = r
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
    rows = _frame_rows(table) if table is not None else table_rows(scene, table_file)
    rows = [r for r in rows if (not models or r.model in models) and (not integrators or r.integrator in integrators)]
    freqs = np.array(sorted({r.frequency_hz for r in rows}), float)
    if not len(freqs):
        raise SelectionError(f"{scene}: the table has no rows for models={models} integrators={integrators}")
    wanted = sorted({abs(float(f)) for f in frequencies})
    notes = []
    if wanted and wanted[-1] > freqs[-1] + 1e-9:
        notes.append(f"{wanted[-1]:g} Hz is above the table's {freqs[-1]:g} Hz: its row is used")

    by_method: dict[tuple[str, str], list[TableRow]] = defaultdict(list)
    for r in rows:
        by_method[(r.model, r.integrator)].append(r)
    best: tuple[float, Plan] | None = None
    for (model, integ), group in sorted(by_method.items()):  # in name order: a tie in cost goes to the first
        ok = _converged_rows(group, tolerance_mm)
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
