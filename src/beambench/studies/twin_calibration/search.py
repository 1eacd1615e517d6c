"""The search of ``beambench calibrate sim`` (:func:`calibrate`), the same for every calibratable rig:

1. *coarse* (on the target frequencies thinned to ``coarse_step_hz``): 1-D lines over each free unknown from the
   prior set's own values, the rig's most monotone unknown first (:func:`prior_lines`, up to ``line_share`` of
   the budget); for rigs with ``landmarks`` (the contact rig's transitions), trust-region steps on a local
   linear model of the landmarks fitted to every point so far (:mod:`.landmark_steps`; they make the diagonal
   moves lines cannot, e.g. more preload with less friction); then, unless every landmark is within
   ``landmark_tolerance``, differential evolution (Sobol start plus the best so far, deferred updating: one
   generation = one parallel batch on the sweep executor) until ~55 % of the budget, a near-zero objective, or
   a stall;
2. *refine*: the best few coarse points re-evaluated on every target frequency, then a 1-D bracket of the rig's
   most monotone unknown (contact rig: the preload, which shifts the whole map) around the best;
3. *verify* (rigs that name how their written protocol runs, ``CalibratableRig.verify``): the best few distinct
   refined points re-run with the protocol's own sweep, windows, noise and seed, and with a second noise seed;
   the winner has the best worse-of-two objective. Rigs with ``run_written`` (the contact rig) write each
   candidate's protocol into ``<out>/<name>_verify/`` and run it as the user will (``beambench run`` on the sim
   backend, then the analysis: :mod:`.written_run`), so the winner's map (the protocol's seed) is the one a run
   of the written protocol shows, label for label (otherwise: the winner's map on every target frequency).

The budget is modelled time, not wall time (:class:`.evaluate.BudgetClock`): each batch adds its evaluations'
simulated seconds at the rig's measured stepping cost, scheduled on the pool's workers. Where a search stops
therefore depends only on what it ran: the same targets and settings give the same search on an idle or a loaded
machine (which only takes longer), and the budget is about the wall time on idle cores.

Every evaluation is appended to ``<out>/<name>.evals.jsonl`` as soon as it finishes; a restart reads it back and
re-uses every point already evaluated (the search is seeded, so it replays the same proposals), which makes a
killed calibration resumable. The search writes the calibrated protocol (and the verify stage's candidates)
into ``out`` and nothing outside it; the report is :mod:`.report`'s (the command writes it).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from beambench.common.console import TimeLeft
from beambench.sim.settings import SimSettings
from beambench.studies.executor import Pool
from beambench.studies.twin_calibration.evaluate import (
    BudgetClock,
    EvalLog,
    Evaluator,
    OutOfTime,
    Point,
    SearchSettings,
    WrittenRun,
    identifiability,
    key,
    makespan,
)
from beambench.studies.twin_calibration.intervals import intervals, landmark_spread
from beambench.studies.twin_calibration.landmark_steps import LandmarkPlan, landmark_steps, within
from beambench.studies.twin_calibration.rig import CalibratableRig, get_rig
from beambench.studies.twin_calibration.targets import CalibrationInputError, Targets
from beambench.studies.twin_calibration.verdict import Verdict, annotate_yaml, judge
from beambench.studies.unknowns import Unknown

__all__ = ["Result", "calibrate"]

DEFAULT_SETTINGS = SearchSettings()


@dataclass(kw_only=True)
class Result:
    """What :func:`calibrate` found (``protocol``: the calibrated protocol it wrote); built by keyword only."""

    rig: str
    values: dict[str, float]
    j: float
    steps: pd.DataFrame
    extras: dict[str, Any]
    protocol: Path
    history: list[dict]
    identifiability: dict[str, Any]
    summary: dict[str, Any]
    evaluations: int
    reused: int
    wall_s: float
    cpu_s: float = 0.0  # CPU seconds of the new evaluations (their worker processes, threads included)
    budget_clock_s: float = 0.0  # the budget's clock at the end (Search.elapsed: the batches' modelled time)
    free: tuple[Unknown, ...] = ()
    settings: SearchSettings = field(default_factory=SearchSettings)
    verdicts: list[Verdict] = field(default_factory=list)  # one per target (:mod:`.verdict`)
    j_stage: str = ""  # which objective ``j`` is (the winner's stage: "verify, worse of two noise seeds" …)


RunAt = Callable[[int], SimSettings | WrittenRun]  # the winner's run at its own noise seed plus k

# The budget's shares (of settings.budget_s) at which each stage stops starting new work. The coarse evolution
# stops at 55 %: the rest pays for the fine stage (the best coarse points re-run on every target frequency, each
# a full stepped sweep, several times a coarse evaluation) and the verify stage (the written protocol, two noise
# seeds each). The fine stage starts no batch after 85 % and the bracket of the monotone unknown no round after
# 90 %, leaving the last 10 % for verify and the report.
COARSE_SHARE = 0.55
FINE_SHARE = 0.85
BRACKET_SHARE = 0.9
# two points this far apart (in the unknowns' ranges) are distinct candidates for the fine and verify stages
DISTINCT = 0.02


def coarse_frequencies(targets: Targets, step_hz: float, lo: float) -> list[float]:
    """The target frequencies thinned to about ``step_hz`` apart (at least ``lo`` Hz)."""
    fs = sorted(f for f in targets.frequencies if f >= lo - 1e-9)
    out: list[float] = []
    for f in fs:
        if not out or f - out[-1] >= step_hz - 1e-9:
            out.append(float(f))
    return out


@dataclass(frozen=True)
class Line:
    """A 1-D search's plan: ``rounds`` rounds of ``n`` points on ``frequencies`` as ``stage``, recorded in the
    history as ``label``, until ``stop()``."""

    frequencies: list[float]
    stage: str
    rounds: int
    n: int
    label: str
    stop: Callable[[], bool] = lambda: False


class Search:
    """One calibration's state: the evaluator, the free and fixed unknowns, each stage's frequencies, the
    history (one row per batch) and the clock."""

    def __init__(
        self, rig: CalibratableRig, targets: Targets, log: EvalLog, settings: SearchSettings, progress: Any = None
    ) -> None:
        self.t_start = time.perf_counter()  # the wall clock, for the report; the budget's is elapsed()
        self.clock = BudgetClock()
        self.rig, self.targets, self.log, self.settings = rig, targets, log, settings
        self.base = rig.base(targets)
        self.free, self.fixed = free_unknowns(rig, settings, rig.boxes(self.base) if rig.boxes else None)
        self.coarse = coarse_frequencies(targets, settings.coarse_step_hz, rig.min_frequency_hz)
        self.fine = [float(f) for f in sorted(targets.frequencies) if f >= rig.min_frequency_hz - 1e-9]
        self.history: list[dict] = []
        self.best: Point | None = None  # the best newly evaluated point (the coarse stage's early stop)
        self.stage_best: dict[str, float] = {}  # per stage: its objectives are comparable only within it
        self.progress = progress
        self.task = (  # the time left of the budget, read each time the line is shown (LogProgress, TimeLeft)
            progress.add_task("calibrating", total=None, left=TimeLeft(settings.budget_s, self.elapsed))
            if progress is not None
            else None
        )
        self.bracketed = next((u for u in self.free if u.name == rig.bracket), None)
        self.t_record = self.last_batch_s = 0.0  # when the last batch was recorded, how long it took (over())

    def start(self, pool: Pool) -> None:
        self.pool = pool
        self.ev = Evaluator(
            pool, self.rig, self.base, self.targets, self.log, self.settings, self._on_eval, clock=self.clock
        )
        self.t_record = self.elapsed()  # the first batch's time starts here, not at the set-up

    def _on_eval(self, p: Point) -> None:
        """Progress: the best objective *of the point's stage* (a coarse map's J is not a verify map's)."""
        if self.best is None or p.j < self.best.j:
            self.best = p
        self.stage_best[p.stage] = min(p.j, self.stage_best.get(p.stage, math.inf))
        if self.progress is not None:
            self.progress.update(
                self.task,
                advance=1,
                description=f"{p.stage} gen {self.ev.generation}: best {p.stage} J {self.stage_best[p.stage]:.3f} "
                f"({self.log.new} run, {self.log.reused} reused)",
            )

    def finish(self, winner: Point, label: str) -> None:
        """The progress line's last state: the winner's objective, as the command's final line reports it."""
        if self.progress is not None:
            self.progress.update(
                self.task,
                description=f"done: J {winner.j:.3f} ({label}) ({self.log.new} run, {self.log.reused} reused)",
            )

    def elapsed(self) -> float:
        """The budget's clock: the modelled time of the batches run so far (:class:`.evaluate.BudgetClock`), not the wall
        clock, so a search stops at the same point on a loaded machine as on an idle one."""
        return self.clock()

    def values_of(self, x: np.ndarray) -> dict[str, float]:
        return {**self.fixed, **{u.name: u.value(float(v)) for u, v in zip(self.free, x)}}

    def record(self, label: str, pts: list[Point], **extra: float) -> None:
        """One history row for a batch (its generation number, best and median objective)."""
        js = [p.j for p in pts] or [math.inf]
        now = self.elapsed()
        self.last_batch_s, self.t_record = now - self.t_record, now
        self.ev.generation += 1
        self.history.append(
            {
                "generation": self.ev.generation - 1,
                "stage": label,
                "best": float(np.min(js)),
                "median": float(np.median(js)),
                "n": len(pts),
                "elapsed_s": now,
                **extra,
            }
        )

    def over(self, share: float, next_batch_s: float | None = None) -> Callable[[], bool]:
        """A stop test: more than ``share`` of the budget spent. With ``plan_finish``: the next batch (its modelled
        time ``next_batch_s`` where the stage knows it, else as long as the last one) would end past the stage's
        deadline — for the coarse shares (≤ ``COARSE_SHARE``) that share of the time left once the later stages
        are reserved (:meth:`reserve_s`), for the fine ones the budget less the verify stage's."""
        budget = self.settings.budget_s
        if not self.settings.plan_finish:
            return lambda: self.elapsed() > share * budget

        def ahead() -> float:
            return self.last_batch_s if next_batch_s is None else next_batch_s

        if share <= COARSE_SHARE:
            return lambda: self.elapsed() + ahead() > share / COARSE_SHARE * (budget - self.reserve_s())
        return lambda: self.elapsed() + ahead() > budget - self.reserve_s(fine=False)

    def fine_batch_s(self, n: int) -> float:
        """The modelled time of a batch of ``n`` fine maps on the pool's workers."""
        one = self.ev.cost_s(self.ev.stage_sim("fine"), len(self.fine))
        return makespan([one] * n, max(1, self.pool.workers))

    def written_batch_s(self, n: int) -> float:
        """The modelled time of ``n`` written-protocol runs on the pool's workers (rigs with ``verify``)."""
        return makespan([self.ev.cost_s(WrittenRun(""), 0)] * n, max(1, self.pool.workers))

    def spread_beyond_verify_s(self) -> float:
        """The modelled time of the written runs at the spread seeds beyond the verify stage's two (rigs with
        ``verify``)."""
        return self.written_batch_s(max(0, self.settings.spread_seeds - 2))

    def reserve_s(self, fine: bool = True) -> float:
        """The modelled time of the stages after the coarse one (``fine``: the fine maps of the best
        ``refine_top`` points too): the verify stage's written-protocol runs (two noise seeds per candidate, and
        the spread seeds beyond them) or, without a verify stage, the winner's spread seeds on every target
        frequency; from the cost per simulated second of the maps so far (0 before the first)."""
        st = self.settings
        out = self.fine_batch_s(st.refine_top) if fine and st.refine_top > 0 else 0.0
        if self.rig.verify is not None and st.verify_top > 0:
            n = 1 if st.verify_fill else st.verify_top
            return out + self.written_batch_s(2 * n) + self.spread_beyond_verify_s()
        return out + self.fine_batch_s(max(0, st.spread_seeds - 1))


def calibrate(
    targets: Targets,
    out_dir: Path,
    name: str,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    settings: SearchSettings = DEFAULT_SETTINGS,
    progress: Any = None,
) -> Result:
    """Fit the twin of ``targets.rig`` to ``targets``; write ``out_dir/<name>.yaml`` (runnable protocol) and its
    parameter set. ``progress``: a rich Progress (or None). The report: :func:`.report.write_report`."""
    from beambench.studies.executor import make_executor
    from beambench.studies.twin_calibration import evaluate

    rig = get_rig(targets.rig)
    out_dir.mkdir(parents=True, exist_ok=True)
    s = Search(rig, targets, EvalLog(out_dir / f"{name}.evals.jsonl"), settings, progress)
    with make_executor(workers, scheduler, preload=(evaluate.__name__,)) as pool:
        s.start(pool)
        reached, start = _lines_and_landmarks(s)
        _evolution(s, start, reached)
        winner = _refine(s)
        if rig.verify is not None and settings.verify_top > 0:
            winner, freqs, run_at = _verify(s, winner, out_dir, name)
            label = "verify: the written protocol's map, worse of two noise seeds"
        else:
            if winner.stage != "fine":  # out of time before the fine stage: still the map on every frequency
                winner = s.ev.batch([winner.values], s.fine, "fine")[0]
            label = "fine: every target frequency"
            fine_sim = s.ev.stage_sim("fine")
            freqs, run_at = s.fine, lambda k: fine_sim.replace(seed=fine_sim.seed + k)
        seeds = seed_spread(s, winner, freqs, run_at)
        ident = identifiability([p for p in s.ev.points if p.stage == "coarse"], s.free)
        fine_pts = [p for p in s.ev.points if p.stage == "fine"]
        if len(fine_pts) > 1:  # the refine/bracket points: on every frequency, so their spread is the sharper one
            ident["fine_spread"] = identifiability(fine_pts, s.free).get("spread", {})
        s.finish(winner, label)
    summary = rig.summary(winner.steps)
    verdicts = _judge(s, winner, ident, seeds)
    wall = time.perf_counter() - s.t_start
    protocol = rig.write(s.base, winner.values, winner.extras, targets, out_dir, name)
    for path in (protocol, out_dir / f"{name}_params.yaml"):
        annotate_yaml(Path(path), verdicts)
    return Result(
        rig=rig.name,
        values=winner.values,
        j=winner.j,
        steps=winner.steps,
        extras=winner.extras,
        protocol=protocol,
        history=s.history,
        identifiability=ident,
        summary=summary,
        evaluations=s.log.new,
        reused=s.log.reused,
        wall_s=wall,
        cpu_s=s.log.cpu_s,
        budget_clock_s=s.elapsed(),
        free=tuple(s.free),
        settings=settings,
        verdicts=verdicts,
        j_stage=label,
    )


def seed_spread(s: Search, winner: Point, freqs: list[float], run_at: RunAt) -> list[Point]:
    """The winner's map at :attr:`SearchSettings.spread_seeds` noise seeds: its own, then ``run_at(k)``, its seed
    plus k (maps already in the log, e.g. the verify stage's second seed, are reused). The verdict reads from
    them how far the twin's own noise moves each target."""
    runs = [run_at(k) for k in range(1, max(1, s.settings.spread_seeds))]
    if not runs:
        return [winner]
    return [winner, *s.ev.batch([winner.values] * len(runs), freqs, "spread", runs=runs)]


def _judge(s: Search, winner: Point, ident: dict[str, Any], seeds: list[Point]) -> list[Verdict]:
    """The verdict per target (:mod:`.verdict`), with the spread of the winner's map over noise ``seeds``; into
    ``ident`` the unknowns' intervals and the landmarks' spread over the near-best refined points
    (:mod:`.intervals`)."""
    if s.rig.checks is None:
        return []
    checks = s.rig.checks(s.targets)
    pts = s.ev.points
    ident["intervals"] = intervals(checks, winner, pts, s.free)
    fine = [p for p in pts if p.stage == "fine"] or [p for p in pts if p.stage == "coarse"]
    if fine:
        jb = min(p.j for p in fine)
        ident["landmark_spread"] = landmark_spread(checks, [p for p in fine if p.j <= jb + max(0.05, 0.25 * jb)])
    searched = {u.name for u in s.free}
    held = [u for u in s.rig.unknowns if u.name not in searched]
    return judge(checks, winner, pts, s.free, seeds, held)


def free_unknowns(
    rig: CalibratableRig, settings: SearchSettings, boxes: dict[str, tuple[float, float]] | None = None
) -> tuple[list[Unknown], dict[str, float]]:
    """The fitted unknowns (``settings.free``, else the rig's default set; the prior set's physical ``boxes``
    replace their generic boxes, :func:`physical`; ``settings.bounds`` narrow them, never widen them) and the
    values of the others (:func:`fixed_values`; ``settings.fixed`` inside the unknowns' bounds)."""
    unknowns = {u.name: physical(u, (boxes or {}).get(u.name)) for u in rig.unknowns}
    rig_unknowns = dict(unknowns)
    names = settings.free or rig.default_free or tuple(unknowns)
    bad = [n for n in (*names, *settings.bounds) if n not in unknowns]
    if bad:
        raise CalibrationInputError(
            f"unknown {bad[0]!r}: the {rig.name} rig's unknowns are {', '.join(u.name for u in rig.unknowns)}"
        )
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise CalibrationInputError(f"free: {twice[0]} is named twice")
    for k, (lo, hi) in settings.bounds.items():
        try:
            unknowns[k] = unknowns[k].within(lo, hi)
        except ValueError as exc:
            raise CalibrationInputError(f"bounds: {exc}") from None
    for k, v in settings.fixed.items():
        u = rig_unknowns.get(k)
        if u is None or not u.lo <= v <= u.hi:
            where = f"outside its bounds [{u.lo:g}, {u.hi:g}]" if u is not None else "not an unknown of the rig"
            raise CalibrationInputError(f"fixed: {k} = {v:g} is {where}")
    free = [unknowns[n] for n in names]
    return free, fixed_values(unknowns, free, settings)


def physical(u: Unknown, box: tuple[float, float] | None) -> Unknown:
    """``u`` searched over the physical ``box`` (None: its own box); its default moves into the box."""
    if box is None:
        return u
    lo, hi = float(box[0]), float(box[1])
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi) or (u.log and lo <= 0):
        raise CalibrationInputError(f"{u.name}: the prior set's physical range gives the box [{lo:g}, {hi:g}]")
    default = None if u.default is None else min(max(u.default, lo), hi)
    return replace(u, lo=lo, hi=hi, default=default)


def _lines_and_landmarks(s: Search) -> tuple[bool, np.ndarray | None]:
    """The prior's lines (1-D brackets of each unknown from the prior, the monotone one — e.g. the preload —
    first), then the landmark steps. Returns whether every landmark is within tolerance (the evolution is then
    skipped) and their best point in the unknowns' coordinates (it joins the evolution's initial population)."""
    rig, settings, br = s.rig, s.settings, s.bracketed
    if br is None or settings.prior_rounds <= 0:
        return False, None
    own = rig.prior(s.base) if rig.prior is not None else {}
    centre = {
        u.name: float(
            np.clip(own[u.name], u.lo, u.hi)
            if u.name in own
            else (1.0 if u.log and u.lo <= 1.0 <= u.hi else _default(u))
        )
        for u in s.free
    }
    order = [br, *(u for u in s.free if u is not br)]
    best = prior_lines(s, {**s.fixed, **centre}, order, s.coarse, max(4, 2 * s.pool.workers))
    reached = False
    if rig.landmarks is not None and settings.landmark_rounds > 0:
        marks = rig.landmarks
        plan = LandmarkPlan(
            s.coarse,
            "coarse",
            settings.landmark_rounds,
            max(2, 2 * s.pool.workers),
            settings.good_enough,
            stop=s.over(settings.landmark_share),
        )
        best = landmark_steps(
            s.ev.batch,
            s.ev.points,
            best,
            s.free,
            lambda steps: marks(steps, s.targets),
            plan,
            on_round=lambda pts, radius: s.record("landmark step", pts, radius=radius),
        )
        reached = within(marks(best.steps, s.targets), settings.landmark_tolerance)
    return reached, np.array([u.coord(best.values[u.name]) for u in s.free])


def _evolution(s: Search, start: np.ndarray | None, reached: bool) -> None:
    """Differential evolution over the free unknowns from :func:`initial_population` with ``start`` (the lines'
    best) as its last member, one generation per parallel batch, until ~55 % of the budget, ``good_enough`` or a
    stall (skipped when the lines and landmark steps reached the targets). scipy is imported only when it runs
    (its import costs seconds of a quick search's start)."""
    settings = s.settings
    late = s.over(COARSE_SHARE)
    if reached or (s.best is not None and s.best.j <= settings.good_enough):
        return  # the lines and landmark steps already reached the targets
    if settings.plan_finish and late():
        return  # no generation fits before the later stages' reserve
    from scipy.optimize import differential_evolution

    init = initial_population(s.free, settings)
    if start is not None:
        init[-1] = start

    def mapper(_func: Any, xs: Any) -> list[float]:
        if (settings.plan_finish or (s.history and s.history[-1]["stage"] == "coarse")) and late():
            raise OutOfTime  # a generation would overrun the coarse stage's share of the budget
        pts = s.ev.batch([s.values_of(np.asarray(x)) for x in xs], s.coarse, "coarse")
        s.record("coarse", pts)
        return [p.j for p in pts]

    stall = {"best": math.inf, "since": 0}

    def stop(intermediate_result: Any) -> bool:
        j = float(intermediate_result.fun)
        if j < stall["best"] - 1e-9:
            stall.update(best=j, since=0)
        else:
            stall["since"] += 1
        return bool(j <= settings.good_enough or late() or stall["since"] >= settings.stall_generations)

    with contextlib.suppress(OutOfTime):
        differential_evolution(
            lambda x: 0.0,  # never called: the mapper evaluates
            [u.bounds for u in s.free],
            maxiter=settings.max_generations,
            init=init,
            rng=settings.seed,
            updating="deferred",
            workers=mapper,
            polish=False,
            tol=0.0,
            mutation=(0.5, 1.0),
            recombination=0.7,
            callback=stop,
        )


def _refine(s: Search) -> Point:
    """The best distinct coarse points on every target frequency, then a bracket of the monotone unknown."""
    settings, br = s.settings, s.bracketed
    ranked = sorted((p for p in s.ev.points if p.stage == "coarse"), key=lambda p: p.j)
    if settings.refine_top <= 0:
        return ranked[0]  # no fine stage: the verify stage (or the winner's spread) runs the best coarse point
    picks: list[dict[str, float]] = []
    for p in ranked:
        if all(_distance(p.values, q, s.free) > DISTINCT for q in picks):
            picks.append(p.values)
        if len(picks) >= settings.refine_top:
            break
    late = s.over(FINE_SHARE, s.fine_batch_s(len(picks)))
    finals = s.ev.batch(picks, s.fine, "fine") if not late() else []
    s.record("fine", finals)
    winner = min(finals, key=lambda p: p.j) if finals else ranked[0]
    per_round = max(2, 2 * s.pool.workers)  # the bracket's points a round
    bracket_late = s.over(BRACKET_SHARE, s.fine_batch_s(per_round))
    if br is not None and finals and settings.bracket_rounds > 0 and not late() and not bracket_late():
        c = br.coord(winner.values[br.name])
        half = 0.06 * (br.bounds[1] - br.bounds[0])
        line = Line(s.fine, "fine", settings.bracket_rounds, per_round, "bracket", bracket_late)
        winner = min(winner, bracket(s, winner.values, br, (c - half, c + half), line), key=lambda p: p.j)
    return winner


def _verify(s: Search, winner: Point, out_dir: Path, name: str) -> tuple[Point, list[float], RunAt]:
    """The best distinct refined points run as the written protocol will run (its sweep, windows, noise and
    seed), each also with a second noise realisation: a label that flips with the noise (a stray ½ or ⅓ at the
    continuous edge) would move a "lowest" transition in the user's run; the worse of the two counts. The
    winner is the best of these maps, which is what the user will see."""
    rig, base = s.rig, s.base
    assert rig.verify is not None
    vfreqs, vsim = rig.verify(base)
    cands = verify_candidates(s, winner)
    seed = int(vsim.seed)
    values = [c.values for c in cands]
    if rig.run_written is not None:  # the candidates' protocols, written and run as the user will run them
        vdir = out_dir / f"{name}_verify"
        vdir.mkdir(exist_ok=True)
        paths = [
            str(
                rig.write(
                    base, c.values, c.extras, s.targets, vdir, f"{name}_{key(rig.name, {}, c.values, [], {})[:8]}"
                )
            )
            for c in cands
        ]
        runs: list[SimSettings | WrittenRun] = [
            *(WrittenRun(p) for p in paths),
            *(WrittenRun(p, seed + 1) for p in paths),
        ]
    else:
        runs = [*([vsim] * len(cands)), *([vsim.replace(seed=seed + 1)] * len(cands))]
    both = s.ev.batch(values * 2, vfreqs, "verify", runs=runs)  # both noise seeds at once: one round of workers
    checked, again = both[: len(cands)], both[len(cands) :]
    worst = [max(a.j, b.j) for a, b in zip(checked, again)]
    s.record("verify", checked + again)
    ib = int(np.argmin(worst))
    best = replace(checked[ib], j=float(worst[ib]), extras={**cands[ib].extras, **checked[ib].extras})
    if rig.run_written is not None:
        path = paths[ib]
        return best, vfreqs, lambda k: WrittenRun(path, seed + k)
    return best, vfreqs, lambda k: vsim.replace(seed=seed + k)


def verify_candidates(s: Search, winner: Point) -> list[Point]:
    """The points the verify stage runs (up to :func:`verify_count`): the winner, then the refined points by
    objective; without a fine stage (``refine_top`` 0) the best coarse points, each at least ``DISTINCT`` apart
    (in the unknowns' ranges) from those already picked, as the fine stage picks its points."""
    fine = sorted((p for p in s.ev.points if p.stage == "fine"), key=lambda p: p.j)
    ranked = fine or sorted((p for p in s.ev.points if p.stage == "coarse"), key=lambda p: p.j)
    apart = 1e-6 if fine else DISTINCT
    n = verify_count(s)
    cands: list[Point] = []
    for p in [winner, *ranked]:
        if all(_distance(p.values, q.values, s.free) > apart for q in cands):
            cands.append(p)
        if len(cands) >= n:
            break
    return cands


def verify_count(s: Search) -> int:
    """How many candidates the verify stage runs: ``verify_top``, or with ``verify_fill`` as many (at least one) as
    the budget left after the spread seeds holds, two written runs each on the pool's workers."""
    st = s.settings
    if not (st.verify_fill and st.plan_finish):
        return max(1, st.verify_top)
    w = max(1, s.pool.workers)
    run_s = s.ev.cost_s(WrittenRun(""), 0)  # > 0: the verify stage runs only for rigs with ``verify``
    left = st.budget_s - s.elapsed() - s.spread_beyond_verify_s()
    rounds = int(left // run_s)  # rounds of the workers, each running w written protocols at once
    return max(1, min(st.verify_top, rounds * w // 2))


def prior_lines(s: Search, start: dict[str, float], order: list[Unknown], freqs: list[float], n: int) -> Point:
    """Coordinate lines from the prior: a 1-D :func:`bracket` of each unknown in ``order`` (the monotone one
    first, over its whole range) at the best point so far, for ``line_cycles`` passes (later passes over ± 15 %
    of each range), until ``line_share`` of the budget. Each unknown of the contact rig moves mainly one landmark
    of the map (the preload all of them, the friction the continuous edge, the damping ⅓ against ½), so lines
    reach a good region in a few dozen maps where the evolution's first generations (one map per point of a
    box-filling design) do not. With ``plan_finish`` the first line runs all its rounds whatever the budget."""
    settings = s.settings
    done = s.over(settings.line_share)
    best: Point | None = None
    cur = dict(start)
    for cycle in range(max(1, settings.line_cycles)):
        for k, u in enumerate(order):
            if best is not None and done():
                return best
            lo, hi = u.bounds
            if cycle > 0:
                c, half = u.coord(cur[u.name]), 0.15 * (hi - lo)
                lo, hi = c - half, c + half
            first = k == 0 and cycle == 0
            rounds = settings.prior_rounds if first else max(1, settings.prior_rounds - 1)
            # a planned budget never cuts the first line short: its rounds are the least search a verify is worth
            stop = (lambda: False) if first and settings.plan_finish else done
            p = bracket(s, cur, u, (lo, hi), Line(freqs, "coarse", rounds, n, "prior line", stop))
            if best is None or p.j < best.j:
                best, cur = p, dict(p.values)
    assert best is not None
    return best


def bracket(s: Search, start: dict[str, float], u: Unknown, interval: tuple[float, float], line: Line) -> Point:
    """A parallel 1-D search of ``u`` (others as in ``start``) inside its bounds: ``line.n`` points spread over
    the interval per round, then the interval shrinks to ± one spacing around the best (the middle of a tie: the
    objective is flat between map changes). Returns the best point seen."""
    lo, hi = max(interval[0], u.bounds[0]), min(interval[1], u.bounds[1])
    n = line.n
    best: Point | None = None
    for _ in range(line.rounds):
        if best is not None and line.stop():
            break
        xs = lo + (np.arange(n) + 0.5) / n * (hi - lo)
        pts = s.ev.batch([{**start, u.name: u.value(float(x))} for x in xs], line.frequencies, line.stage)
        s.record(line.label, pts)
        js = np.array([p.j for p in pts])
        ties = np.flatnonzero(js <= js.min() + 1e-9)
        i = int(ties[len(ties) // 2])
        if best is None or pts[i].j <= best.j:
            best = pts[i]
        step = (hi - lo) / n
        c = float(xs[i])
        lo, hi = max(u.bounds[0], c - step), min(u.bounds[1], c + step)
    assert best is not None
    return best


def initial_population(free: list[Unknown], settings: SearchSettings) -> np.ndarray:
    """Generation 0: a scrambled Sobol design over the box (``popsize`` points)."""
    from scipy.stats import qmc

    lo = np.array([u.bounds[0] for u in free])
    hi = np.array([u.bounds[1] for u in free])
    n = max(5, settings.popsize)
    pts = qmc.Sobol(len(free), scramble=True, seed=settings.seed).random(2 ** math.ceil(math.log2(n)))[:n]
    return lo + pts * (hi - lo)


def fixed_values(unknowns: dict[str, Unknown], free: list[Unknown], settings: SearchSettings) -> dict[str, float]:
    """The values of the unknowns that are not fitted: ``settings.fixed``, else their default — except opt-in
    unknowns, which are left out (the prior parameter set keeps its own value) unless ``settings.fixed`` names
    them."""
    return {
        n: float(settings.fixed.get(n, _default(u)))
        for n, u in unknowns.items()
        if u not in free and (not u.opt_in or n in settings.fixed)
    }


def _default(u: Unknown) -> float:
    if u.default is not None:
        return u.default
    return math.sqrt(u.lo * u.hi) if u.log else 0.5 * (u.lo + u.hi)


def _distance(a: dict[str, float], b: dict[str, float], free: list[Unknown]) -> float:
    d = [(u.coord(a[u.name]) - u.coord(b[u.name])) / (u.bounds[1] - u.bounds[0]) for u in free]
    return float(np.sqrt(np.sum(np.square(d))))
