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
:func:`run_ladder` writes ``ladder_table.csv`` (one row per configuration and frequency), and
:func:`plot_speed_accuracy` / :func:`plot_stability_map` draw the two figures.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pandas as pd
from mujoco.batch import Batch

from beambench.common.figures import new_figure
from beambench.common.types import Floats
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
QUICK = LadderConfig(
    models=("prb3", "rod3g", "rod10"),
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
                for f in cfg.frequencies:
                    rows.append(
                        {
                            **base,
                            "frequency_hz": f,
                            "status": "skipped",
                            "tip_err_mm": np.nan,
                            "rel_dev_converged": np.nan,
                        }
                    )
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


# --------------------------------------------------------------------------------------------- figures
_MODEL_COLORS = {
    "prb3": "tab:blue",
    "rod3gs": "tab:olive",
    "rod3g": "tab:orange",
    "rod5": "tab:green",
    "rod10": "tab:purple",
    "rod20": "tab:brown",
    "rod40": "tab:gray",
}
_INTEGRATOR_MARKERS = {"euler": "v", "implicitfast": "o", "implicit": "s", "rk4": "D", "discrete": "^"}


def _config_label(r: pd.Series) -> str:
    return f"{r.model} {r.integrator} {r.timestep:g}"


def place_labels(
    ax,
    xs: Floats,
    ys: Floats,
    labels: Sequence[str],
    fontsize: float = 7.0,
    avoid_x: Floats = (),
) -> list:
    """Label points so that no two labels overlap each other or any point (greedy, in display space).

    Candidates are offsets around each point at growing distances; the first free one wins (points in
    crowded regions are placed first). A leader line joins a label set far from its point.
    """
    fig = ax.figure
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    pts = ax.transData.transform(np.column_stack([xs, ys]))
    axbox = ax.get_window_extent(renderer)
    r_pt = 4.0 * fig.dpi / 72.0
    occupied = [(x - r_pt, y - r_pt, x + r_pt, y + r_pt) for x, y in pts]
    for xv in avoid_x:  # keep labels off vertical marker lines
        x = ax.transData.transform((xv, 1.0))[0]
        occupied.append((x - 1.5, axbox.y0, x + 1.5, axbox.y1))

    def overlaps(b: tuple[float, float, float, float]) -> bool:
        if b[0] < axbox.x0 or b[2] > axbox.x1 or b[1] < axbox.y0 or b[3] > axbox.y1:
            return True
        return any(b[0] < o[2] and b[2] > o[0] and b[1] < o[3] and b[3] > o[1] for o in occupied)

    # crowded points first
    d = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=2) + np.eye(len(pts)) * 1e9
    order = np.argsort(np.sort(d, axis=1)[:, 0]) if len(pts) > 1 else np.arange(len(pts))
    texts = []
    for k in order:
        t = ax.text(0, 0, labels[k], fontsize=fontsize, transform=None, va="center", ha="left")
        ext = t.get_window_extent(renderer)
        w, hgt = ext.width, ext.height
        placed = None
        for dist in (6, 12, 20, 30, 45, 65, 90, 120):
            dist_px = dist * fig.dpi / 72.0
            for ang in (0, 180, 45, -45, 135, -135, 90, -90, 20, -20, 160, -160, 70, -70, 110, -110):
                cx = pts[k, 0] + dist_px * math.cos(math.radians(ang))
                cy = pts[k, 1] + dist_px * math.sin(math.radians(ang))
                x0 = cx if math.cos(math.radians(ang)) >= -0.1 else cx - w
                if abs(math.cos(math.radians(ang))) < 0.4:
                    x0 = cx - w / 2
                box = (x0, cy - hgt / 2, x0 + w, cy + hgt / 2)
                if not overlaps(box):
                    placed = (box, dist)
                    break
            if placed:
                break
        if placed is None:  # give up gracefully: put it on the point's right, may overlap
            box = (pts[k, 0] + 6, pts[k, 1] - hgt / 2, pts[k, 0] + 6 + w, pts[k, 1] + hgt / 2)
            placed = (box, 6)
        box, dist = placed
        occupied.append(box)
        xd, yd = ax.transData.inverted().transform((box[0], (box[1] + box[3]) / 2))
        t.remove()
        t = ax.text(xd, yd, labels[k], fontsize=fontsize, va="center", ha="left")
        if dist > 6:  # anything but the nearest ring gets a leader line
            near_x = min(max(pts[k, 0], box[0]), box[2])
            near = ax.transData.inverted().transform((near_x, (box[1] + box[3]) / 2))
            ax.plot([xs[k], near[0]], [ys[k], near[1]], lw=0.5, color="0.5", zorder=1)
        texts.append(t)
    return texts


def default_model_sentence(summary: pd.DataFrame) -> str | None:
    """The speed/accuracy chart's message in words: the default model's error against the reference and its cost."""
    default = summary[
        (summary.model == "prb3") & (summary.integrator == "implicitfast") & np.isclose(summary.timestep, 1e-4)
    ]
    if not len(default) or not np.isfinite(default.err_mean_mm.iloc[0]):
        return None
    d = default.iloc[0]
    return (
        f"In words: the default model (PRB3, implicitfast, dt 1e-4 s) is off the 40-segment rod reference by "
        f"{d.err_mean_mm:.2g} mm on average over 5–45 Hz (worst frequency {d.err_max_mm:.2g} mm) and costs "
        f"{d.wall_s_per_10s:.2g} s per 10 s simulated."
    )


def plot_speed_accuracy(summary: pd.DataFrame, path: Path, title: str = "", time_col: str = "wall_s_per_10s") -> Path:
    """Log-log chart: wall s per 10 s simulated vs mean tip error over 5–45 Hz; each model's Pareto front
    (over integrators and timesteps) labelled; the paper's PRB (1.2 s) and FEA (82.5 s) marked.
    ``time_col="cpu_s_per_10s"`` plots thread-CPU time instead (steadier on a shared machine)."""
    from matplotlib.lines import Line2D

    summary = summary.assign(wall_s_per_10s=summary[time_col])
    fig = new_figure(figsize=(11, 7), dpi=110)
    ax = fig.subplots()
    stable = summary[summary.status_band.isin(["ok", "inaccurate"]) & ~summary.is_reference]
    stable = stable.dropna(subset=["err_mean_mm", "wall_s_per_10s"])
    ax.scatter(
        stable.wall_s_per_10s, stable.err_mean_mm, s=8, color="0.8", zorder=2, label="every stable configuration"
    )
    shown = []
    # label each model's Pareto front below the paper model's error (above it every model is just as bad;
    # those configurations stay as grey dots), plus the fastest point of each model
    paper_err = stable[
        (stable.model == "prb3") & (stable.integrator == "implicitfast") & np.isclose(stable.timestep, 1e-4)
    ].err_mean_mm
    cap = 0.5 * float(paper_err.iloc[0]) if len(paper_err) else math.inf
    for model in summary.model.unique():
        front = pareto(stable[stable.model == model])
        if front.empty:
            continue
        front = front[(front.err_mean_mm <= cap) | (front.wall_s_per_10s == front.wall_s_per_10s.min())]
        keep, last = [], math.inf  # along the front, only steps that buy a real (>15 %) gain in accuracy
        for idx, r in front.iterrows():
            if r.err_mean_mm < 0.85 * last:
                keep.append(idx)
                last = r.err_mean_mm
        front = front.loc[keep]
        color = _MODEL_COLORS.get(model, "k")
        ax.plot(front.wall_s_per_10s, front.err_mean_mm, "-", color=color, lw=1, alpha=0.6, zorder=3)
        for _, r in front.iterrows():
            ax.scatter(
                r.wall_s_per_10s, r.err_mean_mm, color=color, marker=_INTEGRATOR_MARKERS[r.integrator], s=30, zorder=4
            )
            shown.append(r)
    # the paper's model at the paper's kind of setting, always shown
    paper = stable[(stable.model == "prb3") & (stable.integrator == "implicitfast") & (stable.timestep == 1e-4)]
    for _, r in paper.iterrows():
        if not any(_config_label(s) == _config_label(r) for s in shown):
            ax.scatter(r.wall_s_per_10s, r.err_mean_mm, color=_MODEL_COLORS["prb3"], marker="o", s=30, zorder=4)
            shown.append(r)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.axvline(PAPER_PRB_S, color="tab:green", ls="--", lw=1)
    ax.axvline(PAPER_FEA_S, color="tab:red", ls="--", lw=1)
    ymax = ax.get_ylim()[1]
    ax.text(PAPER_PRB_S * 1.05, ymax, "paper PRB 1.2 s", color="tab:green", fontsize=8, va="top")
    ax.text(PAPER_FEA_S * 1.05, ymax, "paper FEA 82.5 s", color="tab:red", fontsize=8, va="top")
    xmin, xmax = ax.get_xlim()
    ax.set_xlim(xmin, max(xmax, PAPER_FEA_S * 3))
    ax.set_xlabel(
        "wall s per 10 s simulated (1 thread, median of 3)"
        if time_col.startswith("wall")
        else "thread-CPU s per 10 s simulated (1 thread, median of 3)"
    )
    ax.set_ylabel("mean tip RMS error vs 40-segment rod reference, 5–45 Hz [mm]")

    handles = [Line2D([], [], color=_MODEL_COLORS.get(m, "k"), lw=2, label=m) for m in summary.model.unique()]
    handles += [Line2D([], [], color="k", marker=mk, ls="", label=i) for i, mk in _INTEGRATOR_MARKERS.items()]
    handles.append(Line2D([], [], color="0.8", marker="o", ls="", label="other stable configurations"))
    ax.legend(handles=handles, fontsize=7, loc="lower left", ncol=2)
    ax.set_title(title or "Speed vs accuracy: Pareto front of each model (labels: model integrator dt [s])")
    ax.grid(True, which="both", alpha=0.2)
    sentence = default_model_sentence(summary)
    if sentence:
        fig.text(0.01, 0.005, sentence, fontsize=9, ha="left", va="bottom")
    if shown:
        df = pd.DataFrame(shown)
        place_labels(
            ax,
            df.wall_s_per_10s.to_numpy(),
            df.err_mean_mm.to_numpy(),
            [_config_label(r) for _, r in df.iterrows()],
            avoid_x=(PAPER_PRB_S, PAPER_FEA_S),
        )
    fig.tight_layout(rect=(0, 0.03, 1, 1))  # room for the sentence at the bottom; nothing clipped
    fig.savefig(path, bbox_inches="tight")
    return path


_STATUS_COLORS = {
    "ok": "#2ca02c",
    "inaccurate": "#ffbf00",
    "growing": "#ff7f0e",
    "diverged": "#d62728",
    "skipped": "#dddddd",
}


def plot_stability_map(table: pd.DataFrame, path: Path, models: Sequence[str] | None = None) -> Path:
    """Grid of panels (rows: integrators, columns: models); each panel is timestep × frequency coloured by
    status: ok, inaccurate (> 1 % from converged), growing, diverged, skipped (too costly to run)."""
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    models = list(models or table.model.unique())
    integs = list(table.integrator.unique())
    fig = new_figure(figsize=(2.6 * len(models) + 1, 1.9 * len(integs) + 1), dpi=100)
    axes = fig.subplots(len(integs), len(models), squeeze=False, sharex=True, sharey=True)
    cmap = ListedColormap([_STATUS_COLORS[s] for s in STATUSES])
    freqs = sorted(table.frequency_hz.unique())
    dts = sorted(table.timestep.unique())
    for r, integ in enumerate(integs):
        for c, model in enumerate(models):
            ax = axes[r, c]
            g = table[(table.model == model) & (table.integrator == integ)]
            grid = np.full((len(dts), len(freqs)), STATUSES.index("skipped"))
            for _, row in g.iterrows():
                grid[dts.index(row.timestep), freqs.index(row.frequency_hz)] = STATUSES.index(row.status)
            ax.imshow(
                grid, cmap=cmap, vmin=0, vmax=len(STATUSES) - 1, aspect="auto", origin="lower", interpolation="nearest"
            )
            ax.tick_params(axis="x", labelsize=9, labelrotation=90)
            ax.tick_params(axis="y", labelsize=9)
            if r == 0:
                ax.set_title(f"model {model}", fontsize=11)
            if c == 0:
                ax.set_ylabel(f"{integ}\ntimestep dt (s)", fontsize=10)
            if r == len(integs) - 1:
                ax.set_xlabel("drive frequency (Hz)", fontsize=10)
    # the panels share their axes, so one panel's ticks are every panel's (set per panel, each call re-synced
    # every sibling: 5 s of a 5.1 s figure)
    step = max(1, len(freqs) // 12)  # readable ticks: at most ~12 frequency labels per panel
    axes[0, 0].set_xticks(range(0, len(freqs), step), [f"{f:g}" for f in freqs[::step]])
    axes[0, 0].set_yticks(range(len(dts)), [f"{d:g}" for d in dts])
    fig.suptitle(
        "Stability map, free beam (inaccurate: > 1 % RMS from the same model converged; growing: "
        "amplitude rising; skipped: too costly)",
        fontsize=9,
        y=0.995,
    )
    fig.legend(
        handles=[Patch(color=_STATUS_COLORS[s], label=s) for s in STATUSES],
        loc="upper center",
        ncol=len(STATUSES),
        fontsize=8,
        bbox_to_anchor=(0.5, 0.975),
    )
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    fig.savefig(path)
    return path


def write_outputs(table: pd.DataFrame, out_dir: Path, cfg: LadderConfig) -> dict[str, Path]:
    """CSV (long table + per-configuration summary) and the two figures."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {
        "table": out_dir / "ladder_table.csv",
        "summary": out_dir / "ladder_summary.csv",
        "speed_accuracy": out_dir / "speed_accuracy.png",
        "speed_accuracy_cpu": out_dir / "speed_accuracy_cpu.png",
        "stability_map": out_dir / "stability_map.png",
    }
    table.to_csv(paths["table"], index=False)
    summary = summarize(table, cfg.error_band)
    summary.to_csv(paths["summary"], index=False)
    plot_speed_accuracy(summary, paths["speed_accuracy"])
    plot_speed_accuracy(summary, paths["speed_accuracy_cpu"], time_col="cpu_s_per_10s")
    plot_stability_map(table, paths["stability_map"])
    return paths


__all__ = [
    "FULL",
    "QUICK",
    "LadderConfig",
    "pareto",
    "place_labels",
    "plot_speed_accuracy",
    "plot_stability_map",
    "run_ladder",
    "summarize",
    "time_config",
    "write_outputs",
]
