"""The model ladder's outputs: the long table and its summary as CSV, the speed-vs-accuracy chart and the
stability map."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from beambench.common.figures import new_figure
from beambench.common.types import Floats
from beambench.sim.models.families import PAPER_MODEL
from beambench.studies.ladder.run import (
    PAPER_FEA_S,
    PAPER_PRB_S,
    STATUSES,
    TWIN_MODEL,
    LadderConfig,
    pareto,
    summarize,
)

_MODEL_COLORS = {
    "prb3": "tab:blue",
    "rod3gs": "tab:olive",
    "rod3g": "tab:orange",
    "rod5g": "tab:cyan",
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
        (summary.model == PAPER_MODEL) & (summary.integrator == "implicitfast") & np.isclose(summary.timestep, 1e-4)
    ]
    if not len(default) or not np.isfinite(default.err_mean_mm.iloc[0]):
        return None
    d = default.iloc[0]
    return (
        f"In words: the default model (PRB3, implicitfast, dt 1e-4 s) is off the 40-segment rod reference by "
        f"{d.err_mean_mm:.2g} mm on average over 5–45 Hz (worst frequency {d.err_max_mm:.2g} mm) and costs "
        f"{d.wall_s_per_10s:.2g} s per 10 s simulated."
    )


def ladder_note(cfg: LadderConfig) -> str:
    """What a reduced ladder measured, for its chart ("" for the full ladder)."""
    if cfg.label == "full":
        return ""
    freqs = "/".join(f"{f:g}" for f in cfg.frequencies)
    return (
        f"{cfg.label.upper()} ladder: {freqs} Hz, {cfg.settle_s:g} s settle + {cfg.record_s:g} s recorded, "
        f"reference {cfg.reference[0]} dt {cfg.reference[2]:g} s; timings from runs of ≤ {cfg.timing_seconds:g} s "
        "scaled to 10 s"
    )


def _legend_handles(summary: pd.DataFrame) -> list:
    """The speed/accuracy chart's legend: one line per model, one marker per integrator, the two grey/hollow keys."""
    from matplotlib.lines import Line2D

    handles = [
        Line2D(
            [],
            [],
            color=_MODEL_COLORS.get(m, "k"),
            lw=2,
            label=m + (" (the shipped twins' model)" if m == TWIN_MODEL else ""),
        )
        for m in summary.model.unique()
    ]
    handles += [Line2D([], [], color="k", marker=mk, ls="", label=i) for i, mk in _INTEGRATOR_MARKERS.items()]
    handles.append(
        Line2D([], [], color="k", marker="o", mfc="none", ls="", label="hollow: inaccurate (> 1 % from converged)")
    )
    handles.append(Line2D([], [], color="0.8", marker="o", ls="", label="other stable configurations"))
    return handles


def plot_speed_accuracy(
    summary: pd.DataFrame, path: Path, title: str = "", time_col: str = "wall_s_per_10s", note: str = ""
) -> Path:
    """Log-log chart: wall s per 10 s simulated vs mean tip error over 5–45 Hz; each model's Pareto front
    (over integrators and timesteps) labelled, hollow where it is "inaccurate" (> 1 % from its model converged
    at some frequency of the band); the paper's PRB (1.2 s) and FEA (82.5 s) marked as another CPU's times.
    ``note`` (e.g. :func:`ladder_note`) goes under the title. ``time_col="cpu_s_per_10s"`` plots thread-CPU
    time instead (steadier on a shared machine)."""

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
        (stable.model == PAPER_MODEL) & (stable.integrator == "implicitfast") & np.isclose(stable.timestep, 1e-4)
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
                r.wall_s_per_10s,
                r.err_mean_mm,
                edgecolors=color,
                facecolors="none" if r.status_band == "inaccurate" else color,
                marker=_INTEGRATOR_MARKERS[r.integrator],
                s=34,
                zorder=4,
            )
            shown.append(r)
    # the paper's model at the paper's kind of setting, always shown
    paper = stable[(stable.model == PAPER_MODEL) & (stable.integrator == "implicitfast") & (stable.timestep == 1e-4)]
    for _, r in paper.iterrows():
        if not any(_config_label(s) == _config_label(r) for s in shown):
            ax.scatter(r.wall_s_per_10s, r.err_mean_mm, color=_MODEL_COLORS[PAPER_MODEL], marker="o", s=30, zorder=4)
            shown.append(r)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.axvline(PAPER_PRB_S, color="tab:green", ls="--", lw=1)
    ax.axvline(PAPER_FEA_S, color="tab:red", ls="--", lw=1)
    ymax = ax.get_ylim()[1]
    for x, what, color in ((PAPER_PRB_S, "PRB", "tab:green"), (PAPER_FEA_S, "FEA", "tab:red")):
        ax.text(x * 1.05, ymax, f"paper {what} {x:g} s\n(another CPU, i7-7900K)", color=color, fontsize=8, va="top")
    xmin, xmax = ax.get_xlim()
    ax.set_xlim(xmin, max(xmax, PAPER_FEA_S * 3))
    ax.set_xlabel(
        "wall s per 10 s simulated (1 thread, median of 3)"
        if time_col.startswith("wall")
        else "thread-CPU s per 10 s simulated (1 thread, median of 3)"
    )
    ax.set_ylabel("mean tip RMS error vs 40-segment rod reference, 5–45 Hz [mm]")

    ax.legend(handles=_legend_handles(summary), fontsize=7, loc="lower left", ncol=2)
    head = title or "Speed vs accuracy: Pareto front of each model (labels: model integrator dt [s])"
    ax.set_title(head + ("\n" + note if note else ""))
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


def plot_stability_map(table: pd.DataFrame, path: Path, models: Sequence[str] | None = None, note: str = "") -> Path:
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
            limit = _needed_timestep(g)
            if limit:  # an explicit integrator's whole panel diverged: say which timestep it would need
                ax.text(0.5, 0.5, limit, transform=ax.transAxes, ha="center", va="center", fontsize=8, color="w")
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
        "amplitude rising; skipped: too costly)" + (f"\n{note}" if note else ""),
        fontsize=9,
        y=0.995,
    )
    fig.legend(
        handles=[Patch(color=_STATUS_COLORS[s], label=s) for s in STATUSES],
        loc="upper center",
        ncol=len(STATUSES),
        fontsize=8,
        bbox_to_anchor=(0.5, 0.955 if note else 0.975),
    )
    fig.tight_layout(rect=(0, 0, 1, 0.92 if note else 0.94))
    fig.savefig(path)
    return path


def _needed_timestep(g: pd.DataFrame) -> str:
    """ "needs dt ≤ … s" from the diverged rows' reasons (beambench.sim.engine.stability), "" without one."""
    import re

    reasons = (
        g.loc[g.status == "diverged", "reason"].dropna().astype(str) if "reason" in g else pd.Series([], dtype=str)
    )
    found = [m.group(1) for r in reasons if (m := re.search(r"needs dt ≤ (\S+) s", r))]
    return f"explicit, unstable here:\nneeds dt ≤ {found[0]} s\n(reason column)" if found else ""


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
    note = ladder_note(cfg)
    plot_speed_accuracy(summary, paths["speed_accuracy"], note=note)
    plot_speed_accuracy(summary, paths["speed_accuracy_cpu"], time_col="cpu_s_per_10s", note=note)
    plot_stability_map(table, paths["stability_map"], note=note)
    return paths
