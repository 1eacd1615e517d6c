"""Evaluating points of a calibration: the search's settings, the evaluation log (every point, JSON lines,
re-used on a restart), the evaluator that runs batches of points on the executor through the log, and what the
evaluated points say about how well the data pin each unknown (:func:`identifiability`)."""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from beambench.common.jsonl import append_record, read_records
from beambench.sim.settings import SimSettings
from beambench.studies.executor import Pool, run_tasks
from beambench.studies.twin_calibration.rig import RIGS, CalibratableRig, CalibrationBase, get_rig
from beambench.studies.twin_calibration.targets import Targets
from beambench.studies.unknowns import Unknown

# ------------------------------------------------------------------------------------------------ settings


@dataclass(frozen=True)
class SearchSettings:
    """Knobs of the search; ``quick()`` is a smaller, faster variant (smoke runs, tests)."""

    budget_s: float = 540.0
    # 1 Hz: a stepped map thinned to 2 Hz steps skips the stray ½ steps of the bouncing band and carries a
    # different state into each step; 1 Hz steps with 0.8 + 1.2 s windows give the 2 + 5 s run's map within
    # ~1 Hz (docs/contact-twin.md) at ~2.5 s per map on one core
    coarse_step_hz: float = 1.0
    coarse_settle_s: float = 0.8
    coarse_record_s: float = 1.2
    # the coarse maps' fixed timestep (None: the base's plan, the converged one): a cheaper, less sure map that only
    # steers the search — the fine, bracket and verify maps run at the base's own
    coarse_timestep: float | None = None
    fine_settle_s: float = 1.5
    fine_record_s: float = 2.0
    popsize: int = 16  # points per generation
    max_generations: int = 40
    stall_generations: int = 8
    good_enough: float = 0.01  # objective at which the coarse stage stops
    refine_top: int = 4
    verify_top: int = 3  # distinct best refined points re-run as the written protocol runs (rigs with ``verify``)
    # with plan_finish: the budget reserves the verify of one candidate, and the stage verifies as many more (up to
    # verify_top) as the budget left allows — a search that met its landmarks early spends the rest on them
    verify_fill: bool = False
    bracket_rounds: int = 3
    prior_rounds: int = 3  # rounds of the 1-D bracket along the prior's line before the evolution
    line_cycles: int = 2  # passes of 1-D lines over every free unknown from the prior (search.prior_lines)
    line_share: float = 0.35  # share of the budget the lines may take
    landmark_rounds: int = 10  # trust-region steps on the landmarks' linear model (rigs with ``landmarks``)
    landmark_share: float = 0.5  # share of the budget the lines and the landmark steps may take together
    # landmarks this close to their targets (the rig's units: Hz for the contact rig, one coarse step) end the
    # coarse stage without the evolution; the rest of the budget goes to the refine and verify stages
    landmark_tolerance: float = 1.0
    seed: int = 1
    free: tuple[str, ...] | None = None  # fit only these unknowns (others at their ``fixed`` value)
    fixed: dict[str, float] = field(default_factory=dict)
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)  # per-unknown (lo, hi), inside its own
    max_evals: int | None = None  # stop (as if killed) after this many *new* evaluations
    # noise seeds the winner's map is run at for the verdict (its own first): a miss that another seed meets is the
    # twin's own seed-to-seed spread (irregular regimes that move with the noise), not a bound (verdict)
    spread_seeds: int = 4
    # the budget is the whole search's modelled time (BudgetClock), verify included: a stage starts no batch whose
    # end (its last batch's time) leaves less than the later stages' modelled time (Search.reserve_s). False: the
    # stages stop *starting* work at shares of the budget
    plan_finish: bool = False
    # with plan_finish: the verify stage's written-protocol run is expected to cost this many times a search map per
    # simulated second (plus WRITTEN_EXTRA_S): the session's pipeline, file and analysis, and two runs on
    # two workers contending for more than their core
    written_factor: float = 1.5

    @classmethod
    def quick(cls, **kw: Any) -> SearchSettings:
        base: dict[str, Any] = dict(
            budget_s=150.0,
            coarse_settle_s=0.8,
            coarse_record_s=1.2,
            fine_settle_s=1.0,
            fine_record_s=1.5,
            popsize=6,
            max_generations=12,
            stall_generations=4,
            refine_top=2,
            verify_top=1,  # each candidate is two runs of the written protocol
            spread_seeds=3,
            bracket_rounds=2,
            prior_rounds=2,
            line_cycles=1,
        )
        base.update(kw)
        return cls(**base)

    def window(self, stage: str) -> tuple[float, float]:
        """(settle, record) seconds of a stage's maps."""
        if stage == "coarse":
            return self.coarse_settle_s, self.coarse_record_s
        return self.fine_settle_s, self.fine_record_s


# a rig's evaluation without a measured stepping cost: CPU seconds per simulated second (about the contact twin's)
DEFAULT_CPU_PER_SIM_S = 0.15
# a map costs this much beyond its physics: its model built and compiled, the static sag, the classification
# (contact maps: 0.2-0.4 CPU-s above their stepping cost, measured on the paper's targets at 1e-4 s)
EVAL_OVERHEAD_S = 0.3
# a written protocol's run costs this much beyond its physics at ``written_factor``: the run's start, the session
# file and its analysis (measured: a 28 s session sweep 3.7-4.3 CPU-s, the paper's 294 s sweep 40-42 CPU-s, against
# 3.4 and 35.3 s of stepping at the measured cost: about 1.15x plus a fraction of a second)
WRITTEN_EXTRA_S = 0.5


class OutOfTime(Exception):
    """The coarse stage's share of the budget is spent (raised inside the evolution, caught around it)."""


class Interrupted(Exception):
    """``max_evals`` reached: the calibration stops where a kill would (the log holds every finished point)."""


# ------------------------------------------------------------------------------------------------ evaluation log


def key(rig: str, base: dict, values: dict[str, float], freqs: Sequence[float], sim: dict) -> str:
    """The log key of one evaluation (a hash of everything its result depends on)."""
    blob = json.dumps(
        [rig, base, {k: round(v, 10) for k, v in sorted(values.items())}, [round(f, 6) for f in freqs], sim],
        sort_keys=True,
        default=str,
    )
    return hashlib.sha1(blob.encode()).hexdigest()


def read_log(path: Path) -> dict[str, dict]:
    """The records of an evaluation log by key (the last of a key wins); lines that are not a record (one cut by
    a kill) are skipped. The one place the log is read."""
    out: dict[str, dict] = {}
    if not path.exists():
        return out
    for rec in read_records(path, "evaluation log"):  # a line cut by a kill: skipped with a warning, repaired
        if isinstance(rec, dict) and "key" in rec:
            out[rec["key"]] = rec
    return out


class EvalLog:
    """Every evaluated point, one JSON object per line, appended (and flushed) as each finishes."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.cache: dict[str, dict] = read_log(path)
        self.reused = 0
        self.new = 0
        self.cpu_s = 0.0  # CPU seconds of the new evaluations (each record's ``cpu_s``)

    def get(self, k: str) -> dict | None:
        rec = self.cache.get(k)
        if rec is not None:
            self.reused += 1
        return rec

    def add(self, rec: dict) -> None:
        self.cache[rec["key"]] = rec
        self.new += 1
        self.cpu_s += float(rec.get("cpu_s", 0.0))
        append_record(self.path, rec, default=json_default)  # on a line of its own, after a cut one too


def json_default(o: Any) -> Any:
    """JSON for numpy scalars and arrays (the log and the report)."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)


# ------------------------------------------------------------------------------------------------ evaluation


@dataclass(frozen=True)
class WrittenRun:
    """Run a protocol the calibration wrote as the user will (``CalibratableRig.run_written``), with ``seed``
    instead of its own when not None."""

    protocol: str
    seed: int | None = None


@dataclass(frozen=True)
class Task:
    """One evaluation, as sent to a worker process."""

    rig: str
    base: CalibrationBase
    values: dict[str, float]
    frequencies: list[float]
    run: SimSettings | WrittenRun
    key: str


def evaluate_task(task: Task) -> dict:
    """Executor task: one simulation of a rig's map (runs in a worker process)."""
    rig = get_rig(task.rig)
    t0, c0 = time.perf_counter(), time.process_time()
    if isinstance(task.run, WrittenRun):
        if rig.run_written is None:
            raise ValueError(f"rig {rig.name} cannot run a written protocol")
        out = rig.run_written(Path(task.run.protocol), task.run.seed)
    else:
        out = rig.simulate(task.base, task.values, task.frequencies, task.run)
    out["wall_s"] = time.perf_counter() - t0
    out["cpu_s"] = time.process_time() - c0  # the worker's CPU, its threads included
    return out


@dataclass
class Point:
    """One evaluated point: the values of all unknowns, objective, its terms, the map, extras, stage."""

    values: dict[str, float]
    j: float
    parts: dict[str, float]
    steps: pd.DataFrame
    extras: dict[str, Any]
    stage: str
    generation: int


@dataclass
class BudgetClock:
    """A search's budget clock: the modelled time of every batch run so far — each new evaluation's nominal cost
    (:meth:`Evaluator.cost_s`) scheduled on the pool's workers (:func:`makespan`) — so that where a search stops
    depends on what it ran, never on the machine's load: a rerun stops at the same point."""

    now_s: float = 0.0

    def __call__(self) -> float:
        return self.now_s


class Evaluator:
    """Runs batches of points on the executor, through the log (cache)."""

    def __init__(
        self,
        pool: Pool,
        rig: CalibratableRig,
        base: CalibrationBase,
        targets: Targets,
        log: EvalLog,
        settings: SearchSettings,
        on_eval: Callable[[Point], None] | None = None,
        clock: BudgetClock | None = None,
    ) -> None:
        self.pool, self.rig, self.base, self.targets, self.log = pool, rig, base, targets, log
        self.settings = settings
        self.on_eval = on_eval or (lambda p: None)
        self.points: list[Point] = []
        self.generation = 0
        self.clock = clock or BudgetClock()

    def stage_sim(self, stage: str) -> SimSettings:
        """A stage's simulation settings: the base's with the search's windows (or the rig's own)."""
        settle, record = self.settings.window(stage)
        sim = self.base.sim.replace(settle_s=settle, record_s=record)
        if stage == "coarse" and self.settings.coarse_timestep is not None:
            sim = sim.replace(timestep=self.settings.coarse_timestep)
        return self.rig.stage_sim(stage, sim) if self.rig.stage_sim is not None else sim

    def batch(
        self,
        values: list[dict[str, float]],
        freqs: list[float],
        stage: str,
        runs: Sequence[SimSettings | WrittenRun] | SimSettings | None = None,
    ) -> list[Point]:
        """Evaluate ``values`` at ``freqs`` with the stage's simulation settings (or ``runs``: one for all, or one
        per point)."""
        if runs is None:
            runs = self.stage_sim(stage)
        per = list(runs) if isinstance(runs, Sequence) else [runs] * len(values)
        base = asdict(self.base)
        keys = [key(self.rig.name, base, v, freqs, asdict(r)) for v, r in zip(values, per)]
        todo = [i for i, k in enumerate(keys) if self.log.get(k) is None]
        seen: set[str] = set()
        unique = []  # the first point of each key not in the log, in order
        for i in todo:
            if keys[i] not in seen:
                seen.add(keys[i])
                unique.append(i)
        limit = self.settings.max_evals
        cut = limit is not None and self.log.new + len(unique) > limit
        if limit is not None and cut:
            unique = unique[: max(0, limit - self.log.new)]
        tasks = [Task(self.rig.name, self.base, values[i], list(freqs), per[i], keys[i]) for i in unique]

        def done(task: Task, res: dict) -> None:
            rec = {
                "key": task.key,
                "rig": self.rig.name,
                "values": task.values,
                "frequencies": task.frequencies,
                "sim": asdict(task.run),
                "stage": stage,
                **res,
            }
            self.log.add(rec)
            self.on_eval(self._point(rec, stage))

        if tasks:
            self.clock.now_s += makespan([self.cost_s(t.run, len(t.frequencies)) for t in tasks], self.pool.workers)
            run_tasks(self.pool.executor, evaluate_task, tasks, done)
        if cut:
            raise Interrupted(f"stopped after {limit} new evaluations")
        out = []
        for k in keys:
            p = self._point(self.log.cache[k], stage)
            out.append(p)
            self.points.append(p)
        return out

    def sim_rate(self, sim: SimSettings | None = None) -> float:
        """Nominal seconds per simulated second of one map on one idle worker (``sim``: the base's settings), from
        the rig's measured stepping cost (``CalibratableRig.cpu_per_sim_s``; 0.15 where it names none)."""
        sim = self.base.sim if sim is None else sim
        return self.rig.cpu_per_sim_s(self.base, sim) if self.rig.cpu_per_sim_s is not None else DEFAULT_CPU_PER_SIM_S

    def cost_s(self, run: SimSettings | WrittenRun, n_frequencies: int) -> float:
        """One evaluation's nominal time: its simulated seconds at :meth:`sim_rate` plus ``EVAL_OVERHEAD_S``; a written protocol's run (the
        rig's ``verify`` sweep) at ``written_factor`` times that rate plus ``WRITTEN_EXTRA_S`` (the session's
        pipeline, file and analysis)."""
        if isinstance(run, SimSettings):
            return n_frequencies * (run.settle_s + run.record_s) * self.sim_rate(run) + EVAL_OVERHEAD_S
        if self.rig.verify is None:
            return 0.0
        vfreqs, vsim = self.rig.verify(self.base)
        sim_s = len(vfreqs) * (vsim.settle_s + vsim.record_s)
        return sim_s * self.sim_rate(vsim) * self.settings.written_factor + WRITTEN_EXTRA_S

    def _point(self, rec: dict, stage: str) -> Point:
        steps = pd.DataFrame(rec["steps"])
        j, parts = self.rig.objective(steps, self.targets)
        return Point(dict(rec["values"]), float(j), parts, steps, dict(rec.get("extras", {})), stage, self.generation)


def makespan(costs: list[float], workers: int) -> float:
    """How long ``costs`` take on ``workers`` workers, each task to the first free worker in the order given (as
    the executor hands them out)."""
    lanes = [0.0] * max(1, min(workers, len(costs)))
    for c in costs:
        i = lanes.index(min(lanes))
        lanes[i] += c
    return max(lanes, default=0.0)


# ------------------------------------------------------------------------------------------------ identifiability


def identifiability(points: list[Point], free: list[Unknown]) -> dict[str, Any]:
    """How well the data pin each unknown: the spread of the near-best points (J within
    max(0.05, 25 %) of the best) in each unknown, and the principal directions of the valley — from a quadratic
    fit of J around the best (the Hessian's eigenvectors; small eigenvalue = flat direction) when there are
    enough points, else from the near-best points' covariance (large spread = flat)."""
    if not points:
        return {}
    js = np.array([p.j for p in points])
    jb = float(js.min())
    near = [p for p in points if p.j <= jb + max(0.05, 0.25 * jb)]
    spans = np.array([u.bounds[1] - u.bounds[0] for u in free])
    out: dict[str, Any] = {"best_objective": jb, "near_best_points": len(near), "threshold": jb + max(0.05, 0.25 * jb)}
    out["spread"] = {
        u.name: {
            "min": float(min(p.values[u.name] for p in near)),
            "max": float(max(p.values[u.name] for p in near)),
            "unit": u.unit,
        }
        for u in free
    }
    names = [u.name for u in free]
    U = np.array([[(u.coord(p.values[u.name])) / s for u, s in zip(free, spans)] for p in points])
    ub = U[int(np.argmin(js))]
    d = len(free)
    n_coef = 1 + d + d * (d + 1) // 2
    order = np.argsort(js)[: max(3 * n_coef, 12)]
    if len(order) >= 2 * n_coef:
        X = U[order] - ub
        cols = [np.ones(len(X))] + [X[:, i] for i in range(d)]
        pairs = [(i, k) for i in range(d) for k in range(i, d)]
        cols += [X[:, i] * X[:, k] * (0.5 if i == k else 1.0) for i, k in pairs]
        A = np.column_stack(cols)
        coef, *_ = np.linalg.lstsq(A, js[order], rcond=None)
        H = np.zeros((d, d))
        for c, (i, k) in zip(coef[1 + d :], pairs):
            H[i, k] = H[k, i] = c
        w, v = np.linalg.eigh(H)
        out["hessian_unit"] = H.tolist()
        out["directions"] = [
            {"curvature": float(wi), "direction": dict(zip(names, np.round(v[:, i], 3).tolist()))}
            for i, wi in enumerate(w)
        ]
        out["method"] = "quadratic fit of J on the best points (unknowns scaled to their search range)"
    elif len(near) >= d + 1:
        Un = np.array([[u.coord(p.values[u.name]) / s for u, s in zip(free, spans)] for p in near])
        w, v = np.linalg.eigh(np.cov(Un.T).reshape(d, d))
        out["directions"] = [
            {"spread": float(np.sqrt(max(wi, 0))), "direction": dict(zip(names, np.round(v[:, i], 3).tolist()))}
            for i, wi in enumerate(w[::-1])
        ]
        out["method"] = "covariance of the near-best points (unknowns scaled to their search range)"
    return out


def quick_budget_s(rig: CalibratableRig) -> float:
    """The budget of ``rig``'s ``--quick`` search (its own quick settings over ``SearchSettings.quick``'s):
    the one figure ``calibrate sim --help`` states for ``--quick``."""
    return float(SearchSettings.quick(**dict(rig.quick)).budget_s)


def quick_help() -> str:
    """``--quick``'s time per rig, for ``calibrate sim --help``, from each rig's quick budget."""
    budgets = ", ".join(f"{rig.name} rig {quick_budget_s(rig) / 60:.1f} min" for rig in RIGS.values())
    return (
        f"A smaller, faster search: a budget of {budgets} of modelled time (each run's simulated seconds at the "
        "measured stepping cost, on the workers), about that much wall time on two idle cores plus start-up; the "
        "same search on a loaded machine takes longer (docs/performance.md)."
    )
