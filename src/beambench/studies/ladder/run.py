"""The model-fidelity ladder: beam model × integrator × timestep, speed against accuracy.

For every configuration on the free-beam scene (stage-driven, no contact):

- **accuracy** — tip RMS error (mm) against the reference (a 40-segment rod at a small timestep) over a
  window of the steady state, per drive frequency; summarised as mean and max over 5–45 Hz;
- **speed** — wall seconds per 10 s simulated, one thread, median of ≥ 3 runs (thread CPU time is recorded
  too: on a shared machine it is the steadier figure);
- **stability** — per frequency: ``diverged`` (NaN / MuJoCo warning / tip left the scene), ``growing``
  (the response amplitude grows through the window), ``inaccurate`` (> 1 % RMS deviation from the same model
  converged, i.e. at the smallest timestep with implicitfast) or ``ok``.

Every timestep in a ladder divides the reference's and the window starts on a common step, so the samples of
every run fall exactly on reference samples: no interpolation error enters the comparison.
:func:`run_ladder` returns the table (one row per configuration and frequency);
:mod:`beambench.studies.ladder.figures` writes it with its two figures.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pandas as pd
from mujoco.batch import Batch

from beambench.common.types import Floats
from beambench.sim.engine.stability import unstable_reason
from beambench.sim.engine.stepping import quiet_mujoco_warnings
from beambench.sim.models.registry import beam_model
from beambench.sim.scenes.free_beam import (
    build_free_beam_spec,
    equilibrium_qpos,
    frequency_sweep,
    stage_controls,
)
from beambench.sim.settings import SimSettings

PAPER_PRB_S = 1.2  # paper: 10 s of the PRB model in 1.2 s (i7-7900K)
PAPER_FEA_S = 82.5  # paper: 10 s of the FEA model in 82.5 s
STATUSES = ("ok", "inaccurate", "growing", "diverged", "skipped")
ACCURACY_TOL = 0.01  # relative deviation from the converged result that counts as "inaccurate"
GROWTH_RATIO = 1.05  # amplitude ratio last / first quarter of the window that counts as "growing"

Progress = Callable[[str, float], None]  # (description, fraction of work done in this call)


@dataclass(frozen=True)
class LadderConfig:
    """What a ladder run covers. ``error_band`` bounds the frequencies that enter the mean/max error."""

    models: tuple[str, ...] = ("prb3", "rod3gs", "rod3g", "rod5", "rod10", "rod20", "rod40")
    integrators: tuple[str, ...] = ("euler", "implicitfast", "implicit", "rk4", "discrete")
    # 1.2e-3 = 2β: the largest step at which implicit damping keeps every rod mode stable (β = 6e-4 s)
    timesteps: tuple[float, ...] = (1e-5, 2e-5, 5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 1.2e-3, 2e-3, 5e-3, 1e-2)
    frequencies: tuple[float, ...] = (5, 15, 25, 35, 45, 60, 80)
    error_band: tuple[float, float] = (5.0, 45.0)
    settle_s: float = 0.8
    record_s: float = 0.4
    twist_deg: float = 90.0
    amplitude: float = 0.002
    params: str = "paper"
    reference: tuple[str, str, float] = ("rod40", "implicitfast", 1e-5)
    timing_frequency: float = 25.0
    timing_seconds: float = 10.0  # simulated per timing run (shorter, and scaled, when a run would be slow)
    timing_budget_s: float = 0.5  # wall per timing run above which it is shortened
    timing_repeats: int = 3
    max_sweep_cpu_s: float = 40.0  # skip an accuracy sweep estimated to cost more CPU than this
    cache_dir: str | None = None  # where the reference run is kept between runs (same settings: reused)
    nthread: int | None = None
    label: str = "full"


FULL = LadderConfig()
TWIN_MODEL = "rod5g"  # the shipped contact and walker twins' beam model (protocols/contact_sweep.yaml)
QUICK = LadderConfig(
    models=("prb3", "rod3g", TWIN_MODEL, "rod10"),
    timesteps=(5e-5, 2e-4, 1e-3, 5e-3),
    frequencies=(5, 25, 45),
    settle_s=0.4,
    record_s=0.2,
    reference=("rod40", "implicitfast", 5e-5),
    timing_seconds=1.0,
    timing_budget_s=0.5,
    max_sweep_cpu_s=20.0,
    label="quick",
)


@dataclass
class _Run:
    t_index: np.ndarray  # sample times as multiples of the reference step
    tip: np.ndarray  # [nf, n, 3]
    ok: np.ndarray  # [nf]
    nv: int


def _steps(seconds: float, h: float) -> int:
    return round(float(seconds / h))


def _check_grid(cfg: LadderConfig) -> None:
    h_ref = cfg.reference[2]
    for h in (*cfg.timesteps, cfg.settle_s, cfg.record_s):  # every sample then falls on a reference sample
        r = h / h_ref
        if abs(r - round(r)) > 1e-6:
            raise ValueError(f"{h:g} s is not a multiple of the reference step {h_ref:g} s")


def _cache_path(cfg: LadderConfig, *what) -> Path | None:
    import hashlib
    import json

    if not cfg.cache_dir:
        return None
    key = json.dumps(
        [
            *what,
            cfg.frequencies,
            cfg.settle_s,
            cfg.record_s,
            cfg.twist_deg,
            cfg.amplitude,
            cfg.params,
            cfg.reference[2],
            mujoco.__version__,
        ]
    )
    return Path(cfg.cache_dir) / f"run_{hashlib.sha1(key.encode()).hexdigest()[:16]}.npz"


def _sweep(model: str, integrator: str, h: float, cfg: LadderConfig) -> _Run:
    """One accuracy sweep (cached in ``cfg.cache_dir``, so an interrupted ladder resumes where it stopped)."""
    path = _cache_path(cfg, model, integrator, h)
    if path is not None and path.exists():
        z = np.load(path)
        return _Run(z["t_index"], z["tip"], z["ok"], int(z["nv"]))
    run = _run_sweep(model, integrator, h, cfg)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, t_index=run.t_index, tip=run.tip, ok=run.ok, nv=run.nv)
    return run


def _run_sweep(model: str, integrator: str, h: float, cfg: LadderConfig) -> _Run:
    bm = beam_model(model, cfg.params)
    settings = SimSettings(
        settle_s=cfg.settle_s,
        record_s=cfg.record_s,
        twist_deg=cfg.twist_deg,
        amplitude_m=cfg.amplitude,
        integrator=integrator,
        timestep=h,
        nthread=cfg.nthread,
    )
    r = frequency_sweep(bm, cfg.frequencies, settings)
    h_ref = cfg.reference[2]
    idx = np.rint(r.t / h_ref).astype(np.int64)
    return _Run(idx, r.tip, r.ok, int(r.info["nv"]))


def _cached_reference(cfg: LadderConfig) -> _Run:
    """The reference sweep, reused from ``cfg.cache_dir`` when it was run with the same settings."""
    import hashlib
    import json

    key = json.dumps(
        [
            cfg.reference,
            cfg.frequencies,
            cfg.settle_s,
            cfg.record_s,
            cfg.twist_deg,
            cfg.amplitude,
            cfg.params,
            mujoco.__version__,
        ]
    )
    path = None
    if cfg.cache_dir:
        path = Path(cfg.cache_dir) / f"reference_{hashlib.sha1(key.encode()).hexdigest()[:12]}.npz"
        if path.exists():
            z = np.load(path)
            return _Run(z["t_index"], z["tip"], z["ok"], int(z["nv"]))
    ref = _sweep(*cfg.reference, cfg)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, t_index=ref.t_index, tip=ref.tip, ok=ref.ok, nv=ref.nv, key=key)
    return ref


def _compare(run: _Run, ref: _Run) -> tuple[np.ndarray, np.ndarray]:
    """RMS tip distance to ``ref`` (m) and the same relative to ref's RMS excursion, per frequency, over the
    sample times both runs share (all of ``run``'s when ``ref`` is on the finest grid)."""
    common, i_run, i_ref = np.intersect1d(run.t_index, ref.t_index, assume_unique=True, return_indices=True)
    if len(common) < max(2, 0.2 * len(run.t_index)):
        raise ValueError("too few sample times shared with the comparison run")
    r = ref.tip[:, i_ref, :]
    d = run.tip[:, i_run, :] - r
    rms = np.sqrt(np.mean(np.sum(d**2, axis=2), axis=1))
    exc = np.sqrt(np.mean(np.sum((r - r.mean(axis=1, keepdims=True)) ** 2, axis=2), axis=1))
    return rms, rms / exc


def _growing(tip: np.ndarray, t_index: np.ndarray, h_ref: float, freqs: Floats) -> np.ndarray:
    """Response amplitude (RMS excursion) over the last drive period of the window exceeds that over the first
    by more than ``GROWTH_RATIO`` (needs two whole periods in the window; else False)."""
    out = np.zeros(len(freqs), bool)
    t = t_index * h_ref
    for j, f in enumerate(freqs):
        period = 1.0 / f
        first = t < t[0] + period - 1e-12
        last = t > t[-1] - period + 1e-12
        if t[-1] - t[0] < 2 * period - 1e-9 or first.sum() < 2:
            continue
        a, b = tip[j, first], tip[j, last]
        amp = [np.sqrt(np.mean(np.sum((x - x.mean(axis=0)) ** 2, axis=1))) for x in (a, b)]
        with np.errstate(invalid="ignore"):
            out[j] = bool(amp[1] > GROWTH_RATIO * amp[0])
    return out


def time_config(model: str, integrator: str, h: float, cfg: LadderConfig) -> tuple[float, float, float, float]:
    """(median wall s, min wall s, median thread-CPU s) per 10 s simulated on one thread, and the simulated
    seconds each timed run covered. Runs longer than ``timing_budget_s`` are shortened and scaled."""
    bm = beam_model(model, cfg.params)
    m = build_free_beam_spec(bm, cfg.twist_deg, integrator, h).compile()
    q0 = equilibrium_qpos(m)
    d = mujoco.MjData(m)
    d.qpos[:] = q0
    mujoco.mj_forward(m, d)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    dof = m.jnt_dofadr[m.joint("stage").id]
    mass = float(full[dof, dof])
    batch = Batch(m, nsim=1, nthread=1)

    def run(nstep: int) -> tuple[float, float]:
        batch.reset(stage=mujoco.mjtStage.mjSTAGE_NONE)
        batch.qpos[:] = q0
        ctrl, v0 = stage_controls(cfg.timing_frequency, cfg.amplitude, h, nstep, mass, integrator)
        qv = np.zeros((1, m.nv))
        qv[0, dof] = v0
        batch.qvel[:] = qv
        batch.forward()
        c = ctrl[None, :, None]
        w0, c0 = time.perf_counter(), time.thread_time()
        batch.rollout(nstep, control=c, record=("sensordata",))
        return time.perf_counter() - w0, time.thread_time() - c0

    probe = max(200, _steps(0.02, h))
    w, _ = run(probe)
    est = w / probe * _steps(cfg.timing_seconds, h)
    seconds = cfg.timing_seconds if est <= cfg.timing_budget_s else cfg.timing_seconds * cfg.timing_budget_s / est
    nstep = max(probe, _steps(seconds, h))
    walls, cpus = zip(*(run(nstep) for _ in range(max(3, cfg.timing_repeats))))
    scale = 10.0 / (nstep * h)
    return float(np.median(walls) * scale), float(np.min(walls) * scale), float(np.median(cpus) * scale), nstep * h


def _diverged_reason(model: str, integrator: str, h: float, cfg: LadderConfig) -> str:
    """Why MuJoCo stopped this configuration's runs (beambench.sim.engine.stability)."""
    m = build_free_beam_spec(beam_model(model, cfg.params), cfg.twist_deg, integrator, h).compile()
    return unstable_reason(m, integrator, equilibrium_qpos(m))


def _cost_probe(model: str, cfg: LadderConfig) -> float:
    """Seconds per step of ``model`` (implicitfast, one thread), for budgeting."""
    m = build_free_beam_spec(beam_model(model, cfg.params), cfg.twist_deg, "implicitfast", 1e-4).compile()
    d = mujoco.MjData(m)
    mujoco.mj_step(m, d, nstep=50)
    t0 = time.perf_counter()
    mujoco.mj_step(m, d, nstep=1000)
    return (time.perf_counter() - t0) / 1000


_INTEGRATOR_COST = {"euler": 1.0, "implicitfast": 1.0, "implicit": 1.3, "rk4": 4.0, "discrete": 1.1}


def run_ladder(cfg: LadderConfig = FULL, progress: Progress | None = None) -> pd.DataFrame:
    """Measure every configuration; returns the long table (one row per configuration × frequency)."""
    with quiet_mujoco_warnings():
        return _run_ladder(cfg, progress)


def _skipped_rows(base: dict, cost: float, cfg: LadderConfig) -> list[dict]:
    """The rows of a configuration whose sweep would cost more than one sweep's CPU budget (not run)."""
    reason = f"estimated {cost:.3g} CPU s > the {cfg.max_sweep_cpu_s:g} s budget of one sweep"
    return [
        {
            **base,
            "frequency_hz": f,
            "status": "skipped",
            "tip_err_mm": np.nan,
            "rel_dev_converged": np.nan,
            "reason": reason,
        }
        for f in cfg.frequencies
    ]


def _run_ladder(cfg: LadderConfig, progress: Progress | None) -> pd.DataFrame:
    _check_grid(cfg)
    say = progress or (lambda desc, frac: None)
    t_sim = len(cfg.frequencies) * (cfg.settle_s + cfg.record_s)
    per_step = {m: _cost_probe(m, cfg) for m in cfg.models}
    per_step.setdefault(cfg.reference[0], _cost_probe(cfg.reference[0], cfg))
    configs = [(m, i, h) for m in cfg.models for i in cfg.integrators for h in cfg.timesteps]

    def sweep_cost(m: str, i: str, h: float) -> float:
        return per_step[m] * _INTEGRATOR_COST[i] * t_sim / h

    total = sum(min(sweep_cost(*c), cfg.max_sweep_cpu_s) for c in configs) + sweep_cost(*cfg.reference)
    total += len(configs) * cfg.timing_repeats * min(cfg.timing_budget_s, 0.2)
    done = 0.0

    def tick(desc: str, cost: float) -> None:
        nonlocal done
        done += cost
        say(desc, min(1.0, cost / total))

    ref_m, ref_i, ref_h = cfg.reference
    say(f"reference {ref_m} {ref_i} dt={ref_h:g}", 0.0)
    ref = _cached_reference(cfg)
    tick(f"reference {ref_m} {ref_i} dt={ref_h:g}", sweep_cost(ref_m, ref_i, ref_h))
    if not ref.ok.all():
        raise RuntimeError("the reference run diverged")

    rows: list[dict] = []
    for model in cfg.models:
        runs: dict[tuple[str, float], _Run] = {}
        # the converged result: implicitfast at the smallest timestep affordable for this model
        affordable = [
            h
            for h in sorted(cfg.timesteps)
            if (model, "implicitfast", h) == cfg.reference
            or sweep_cost(model, "implicitfast", h) <= cfg.max_sweep_cpu_s
        ]
        conv_key = ("implicitfast", affordable[0] if affordable else min(cfg.timesteps))
        order = [conv_key] + [(i, h) for i in cfg.integrators for h in sorted(cfg.timesteps) if (i, h) != conv_key]
        for integ, h in order:
            desc = f"{model} {integ} dt={h:g}"
            cost = sweep_cost(model, integ, h)
            base = dict(model=model, integrator=integ, timestep=h, label=cfg.label)
            if (model, integ, h) == cfg.reference:
                run = ref
            elif cost > cfg.max_sweep_cpu_s:
                rows += _skipped_rows(base, cost, cfg)
                tick(desc + " (skipped)", cfg.max_sweep_cpu_s)
                continue
            else:
                say(desc, 0.0)
                run = _sweep(model, integ, h, cfg)
            runs[(integ, h)] = run
            err, _ = _compare(run, ref)
            conv = runs.get(conv_key)
            rel = _compare(run, conv)[1] if conv is not None else np.full(len(cfg.frequencies), np.nan)
            grow = _growing(run.tip, run.t_index, cfg.reference[2], cfg.frequencies)
            err = np.where(run.ok, err, np.nan)
            wall = wall_min = cpu = timed = np.nan
            why = "" if run.ok.all() else _diverged_reason(model, integ, h, cfg)
            if run.ok.any():
                wall, wall_min, cpu, timed = time_config(model, integ, h, cfg)
            for j, f in enumerate(cfg.frequencies):
                if not run.ok[j]:
                    status = "diverged"
                elif grow[j]:
                    status = "growing"
                elif rel[j] > ACCURACY_TOL:
                    status = "inaccurate"
                else:
                    status = "ok"
                rows.append(
                    {
                        **base,
                        "frequency_hz": f,
                        "status": status,
                        "tip_err_mm": err[j] * 1e3,
                        "rel_dev_converged": rel[j],
                        "nv": run.nv,
                        "wall_s_per_10s": wall,
                        "wall_min_s_per_10s": wall_min,
                        "cpu_s_per_10s": cpu,
                        "timed_sim_s": timed,
                        "reason": why if status == "diverged" else "",
                    }
                )
            tick(desc, min(cost, cfg.max_sweep_cpu_s))
    table = pd.DataFrame(rows)
    table["is_reference"] = [
        (m, i, h) == cfg.reference for m, i, h in zip(table.model, table.integrator, table.timestep)
    ]
    return table


def summarize(table: pd.DataFrame, band: tuple[float, float] = (5.0, 45.0)) -> pd.DataFrame:
    """One row per configuration: mean/max error over ``band``, wall time and the worst status anywhere."""
    rank = {s: i for i, s in enumerate(STATUSES)}
    out = []
    for (m, i, h), g in table.groupby(["model", "integrator", "timestep"], sort=False):
        inband = g[(g.frequency_hz >= band[0]) & (g.frequency_hz <= band[1])]
        worst = max(g.status, key=lambda s: rank[s])
        worst_band = max(inband.status, key=lambda s: rank[s]) if len(inband) else "skipped"
        out.append(
            {
                "model": m,
                "integrator": i,
                "timestep": h,
                "nv": g["nv"].max() if "nv" in g else np.nan,
                "err_mean_mm": inband.tip_err_mm.mean(),
                "err_max_mm": inband.tip_err_mm.max(),
                "wall_s_per_10s": g.wall_s_per_10s.max() if "wall_s_per_10s" in g else np.nan,
                "wall_min_s_per_10s": g.wall_min_s_per_10s.max() if "wall_min_s_per_10s" in g else np.nan,
                "cpu_s_per_10s": g.cpu_s_per_10s.max() if "cpu_s_per_10s" in g else np.nan,
                "status_band": worst_band,
                "status_all": worst,
                "is_reference": bool(g.is_reference.any()) if "is_reference" in g else False,
                "label": str(g["label"].iloc[0]) if "label" in g else "",
            }
        )
    return pd.DataFrame(out)


def pareto(summary: pd.DataFrame) -> pd.DataFrame:
    """Configurations no other beats in both wall time and mean error (stable in the error band)."""
    s = summary[(summary.status_band.isin(["ok", "inaccurate"])) & ~summary.is_reference]
    s = s.dropna(subset=["err_mean_mm", "wall_s_per_10s"]).sort_values(["wall_s_per_10s", "err_mean_mm"])
    keep, best = [], math.inf
    for idx, r in s.iterrows():
        if r.err_mean_mm < best:
            keep.append(idx)
            best = r.err_mean_mm
    return s.loc[keep]


__all__ = [
    "FULL",
    "QUICK",
    "TWIN_MODEL",
    "LadderConfig",
    "pareto",
    "run_ladder",
    "summarize",
    "time_config",
]
