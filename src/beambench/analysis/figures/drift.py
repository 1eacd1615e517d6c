"""Drift at the reference steps: each reference result against session time with its fitted trend per hour
(:mod:`beambench.analysis.drift`); only drawn for sessions with three or more reference steps."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from beambench.analysis.drift import DRIFT_METRICS, drift_table, reference_steps
from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import SESSION_COLORS, legend_below, new_figure

if TYPE_CHECKING:
    from beambench.analysis.session import SessionAnalysis

MIN_REFERENCES = 3


@FIGURES.add(
    "drift",
    rigs=("contact",),
    caption="Drift at the reference steps: contacts per cycle, peak normal force, tip ellipse axes and motor current "
    "of each reference step against session time, with the least-squares trend. Each panel's title gives the trend "
    "per hour ± its standard error; 'drift' where it exceeds the step-to-step noise (t-test on the slope, 5 %, and "
    "a change over the session larger than the analysis resolves), else 'within noise'. drift.csv has the numbers.",
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
    refs = [(a, reference_steps(a.table)) for a in analyses]
    refs = [(a, r) for a, r in refs if len(r) >= MIN_REFERENCES]
    if not refs:
        return None
    metrics = [m for m in DRIFT_METRICS if any(m in r and r[m].notna().any() for _, r in refs)]
    if not metrics:
        return None
    ncol = min(3, len(metrics))
    nrow = -(-len(metrics) // ncol)
    fig = new_figure((4.4 * ncol, 3.3 * nrow + 0.6))
    axes = np.atleast_1d(fig.subplots(nrow, ncol, squeeze=False)).ravel()
    for ax in axes[len(metrics) :]:
        ax.set_visible(False)
    span_s = max(float(r["t_h"].max()) for _, r in refs) * 3600
    unit, per_s = ("s", 1.0) if span_s < 120 else (("min", 60.0) if span_s < 7200 else ("h", 3600.0))
    for si, (a, ref) in enumerate(refs):
        trend = {str(row["metric"]): row for row in drift_table(a.table).to_dict("records")}
        color = SESSION_COLORS[si % len(SESSION_COLORS)]
        who = f" ({a.label})" if len(refs) > 1 else ""
        for ax, m in zip(axes, metrics):
            if m not in ref or not ref[m].notna().any():
                continue
            tx = ref["t_h"].to_numpy(float) * 3600 / per_s
            y = ref[m].to_numpy(float)
            ax.plot(tx, y, "o", color=color, ms=5, label="reference steps" + who)
            r = trend.get(m)
            if r is not None and np.isfinite(float(r["trend_per_h"])):
                tt = np.array([tx.min(), tx.max()])
                t_mean = float(np.mean(tx[np.isfinite(y)])) * per_s / 3600
                fit = float(r["mean"]) + float(r["trend_per_h"]) * (tt * per_s / 3600 - t_mean)
                verdict = "drift" if bool(r["significant"]) else "within noise"
                ax.plot(tt, fit, "-", color=color, lw=1.2, label="linear trend" + who)
                ax.set_title(
                    f"{DRIFT_METRICS[m]}\n{r['trend_per_h']:+.3g} ± {r['trend_se_per_h']:.2g} /h: {verdict}",
                    color="#d62728" if bool(r["significant"]) else "0.2",
                )
            else:
                ax.set_title(DRIFT_METRICS[m])
            ax.set(xlabel=f"time since the first reference step ({unit})", ylabel=DRIFT_METRICS[m])
    fig.suptitle(
        "Reference steps at "
        + ", ".join(f"{float(r['frequency_hz'].iloc[0]):g} Hz" for _, r in refs)
        + " over the session"
    )
    legend_below(fig, axes[: len(metrics)], ncol=4)
    fig.savefig(path)
    return path
