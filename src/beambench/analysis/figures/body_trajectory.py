"""The walker's body along the slider through the record window of a few steps (the paper's walking points, the
fastest step and a spread of others), one line each with its frequency and speed in the legend."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import SESSION_COLORS, new_figure
from beambench.common.figures import legend_below

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from beambench.analysis.session_analysis import SessionAnalysis, StepResult

MAX_LINES = 6  # more overlaid lines are no longer told apart
PAPER_HZ = (23.0, 65.0)  # the paper's two walking points (Sec. IV-B)
LINE_COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b"]


@FIGURES.add(
    "body_trajectory",
    scenes=lambda s: s.walks,
    caption=f"The body marker's forward position through the record window of at most {MAX_LINES} steps, from "
    "where the window starts: the paper's walking points (23 and 65 Hz), the fastest step and steps spread over the "
    "sweep (the title says how many of the session's steps are shown; the walking-speed figure has every step). "
    "A straight line is a steady speed (its slope is the walking-speed figure's point); a wavy one, a gait that "
    "surges and stalls within the window.",
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
    fig = body_figure(analyses)
    if fig is None:
        return None
    fig.savefig(path)
    return path


def chosen_steps(steps: list[StepResult], n: int = MAX_LINES) -> list[StepResult]:
    """At most ``n`` steps in frequency order: the paper's walking points, the fastest |speed|, then steps evenly
    spread over the sweep's frequencies."""
    if len(steps) <= n:
        return sorted(steps, key=lambda r: r.frequency_hz)
    by_f = sorted(steps, key=lambda r: r.frequency_hz)
    out: list[StepResult] = []
    for hz in PAPER_HZ:
        r = next((r for r in by_f if r.frequency_hz == hz), None)
        if r is not None:
            out.append(r)
    speeds = [(abs(float(r.row.get("body_speed_mm_s", np.nan))), r) for r in by_f]
    speeds = [(s, r) for s, r in speeds if np.isfinite(s)]
    if speeds:
        fastest = max(speeds, key=lambda x: x[0])[1]
        if fastest not in out:
            out.append(fastest)
    for i in np.linspace(0, len(by_f) - 1, n).round().astype(int):
        if len(out) >= n:
            break
        if by_f[i] not in out:
            out.append(by_f[i])
    return sorted(out, key=lambda r: r.frequency_hz)


def body_figure(analyses: list[SessionAnalysis]) -> Figure | None:
    """One panel per session, a line per chosen step; None without body tracks."""
    runs = [(a, [r for r in a.steps if len(r.body_x_mm) > 2]) for a in analyses]
    runs = [(a, steps) for a, steps in runs if steps]
    if not runs:
        return None
    fig = new_figure((8.5 if len(runs) == 1 else 5.2 * len(runs), 5.2))
    axes = fig.subplots(1, len(runs), sharey=True, squeeze=False)[0]
    freqs = [r.frequency_hz for r in chosen_steps(runs[0][1])]  # every panel the same frequencies, same colours
    for ax, (si, (a, steps)) in zip(axes, enumerate(runs)):
        shown = [r for f in freqs for r in steps[:] if r.frequency_hz == f][: len(freqs)]
        for r in shown:
            x = r.body_x_mm - np.nanmedian(r.body_x_mm[: max(3, len(r.body_x_mm) // 50)])
            speed = float(r.row.get("body_speed_mm_s", np.nan))
            shown_speed = f"{speed:+.0f}" if round(speed) else "0"
            label = f"{r.frequency_hz:g} Hz ({shown_speed} mm/s)" if len(runs) == 1 else f"{r.frequency_hz:g} Hz"
            ax.plot(r.body_t, x, color=LINE_COLORS[freqs.index(r.frequency_hz) % len(LINE_COLORS)], lw=1.1, label=label)
        ax.axhline(0, color="0.3", lw=0.8)
        which = f"{len(shown)} of {len(steps)} steps" if len(shown) < len(steps) else f"all {len(steps)} steps"
        head = a.label if len(runs) > 1 else "Body along the slider"
        ax.set(xlabel="time in the record window (s)", title=f"{head}: {which}")
        if len(runs) > 1:
            ax.title.set_color(SESSION_COLORS[si % 4])
    axes[0].set_ylabel("forward displacement (mm, + forward)")
    legend_below(fig, axes, ncol=6 if len(runs) > 1 else 3)
    return fig
