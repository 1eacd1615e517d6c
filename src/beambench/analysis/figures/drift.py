"""Drift at the reference steps: each reference result against session time with its fitted trend per hour
(:mod:`beambench.analysis.drift`); only drawn for sessions with three or more reference steps."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from beambench.analysis.drift import DRIFT_METRICS, drift_table, reference_steps
from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import SESSION_COLORS, new_figure
from beambench.common.figures import legend_below

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import SessionAnalysis

MIN_REFERENCES = 3


@FIGURES.add(
    "drift",
    scenes=lambda s: s.plate,
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
    verdicts: dict[str, list[tuple[str, bool]]] = {m: [] for m in metrics}
    for si, (a, ref) in enumerate(refs):
        trend = {str(row["metric"]): row for row in drift_table(a.table).to_dict("records")}
        color = SESSION_COLORS[si % len(SESSION_COLORS)]
        who = f" ({a.label})" if len(refs) > 1 else ""
        for ax, m in zip(axes, metrics):
            if m in ref and ref[m].notna().any():
                v = _panel(ax, ref, m, trend.get(m), per_s, color, who)
                if v is not None:
                    verdicts[m].append((f"{a.label}: {v[0]}" if who else v[0], v[1]))
    for ax, m in zip(axes, metrics):
        lines = [DRIFT_METRICS[m], *(text for text, _ in verdicts[m])]
        ax.set_title("\n".join(lines), color="#d62728" if any(sig for _, sig in verdicts[m]) else "0.2")
        ax.set(xlabel=f"time since the first reference step ({unit})", ylabel=DRIFT_METRICS[m])
    freqs = sorted({float(r["frequency_hz"].iloc[0]) for _, r in refs})
    fig.suptitle("Reference steps at " + ", ".join(f"{f:g} Hz" for f in freqs) + " over the session")
    legend_below(fig, axes[: len(metrics)], ncol=4)
    fig.savefig(path)
    return path


def _panel(
    ax: Any, ref: pd.DataFrame, m: str, r: Mapping[Any, Any] | None, per_s: float, color: str, who: str
) -> tuple[str, bool] | None:
    """One session's reference values of ``m`` and their trend line; returns the title's verdict (text,
    significant), None without a trend."""
    tx = ref["t_h"].to_numpy(float) * 3600 / per_s
    y = ref[m].to_numpy(float)
    ax.plot(tx, y, "o", color=color, ms=5, label="reference steps" + who)
    if r is None or not np.isfinite(float(r["trend_per_h"])):
        return None
    tt = np.array([tx.min(), tx.max()])
    t_mean = float(np.mean(tx[np.isfinite(y)])) * per_s / 3600
    ax.plot(tt, float(r["mean"]) + float(r["trend_per_h"]) * (tt * per_s / 3600 - t_mean), "-", color=color, lw=1.2)
    ax.lines[-1].set_label("linear trend" + who)
    sig = bool(r["significant"])
    verdict = "drift" if sig else "within noise"
    return f"{float(r['trend_per_h']):+.3g} ± {float(r['trend_se_per_h']):.2g} /h: {verdict}", sig
