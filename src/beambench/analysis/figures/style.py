"""What every report figure shares: colours, the matplotlib style, a figure of its own, the legend, and small
look-ups on a session analysis."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import pandas as pd

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from beambench.analysis.session_analysis import SessionAnalysis, StepResult

REGIME_COLORS = {
    "1": "#1f77b4",
    "1/2": "#ff7f0e",
    "1/3": "#2ca02c",
    "1/4": "#d62728",
    "1/5": "#9467bd",
    "1/6": "#8c564b",
    "2": "#e377c2",
    "3": "#bcbd22",
    "continuous": "#222222",
    "none": "#b0b0b0",
    "irregular": "#7f7f7f",
    "": "#b0b0b0",
}
REGIME_NAMES = {
    "1": "1 contact / cycle",
    "1/2": "1 contact / 2 cycles",
    "1/3": "1 contact / 3 cycles",
    "1/4": "1 contact / 4 cycles",
    "continuous": "continuous contact",
    "none": "no contact",
    "irregular": "irregular",
}
SESSION_COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd"]
SESSION_MARKERS = ["o", "s", "^", "D"]
FOOT_COLORS = {"foot_left": "#1f77b4", "foot_right": "#d62728"}
MARKER_NAMES = {"foot_left": "left foot", "foot_right": "right foot"}


def marker_name(m: str) -> str:
    """How figures name a marker: ``foot_left`` → "left foot"."""
    return MARKER_NAMES.get(m, m.replace("_", " "))


PATH_CYCLES = 6
R2_SENSE_MIN = 0.5  # below this share of the path explained by the first-harmonic ellipse, its sense is uncertain
UNCERTAIN = "0.55"  # colour of an uncertain sense


def new_figure(figsize: tuple[float, float], layout: Literal["constrained"] | None = "constrained") -> Figure:
    """A figure of its own (not pyplot's): constrained layout keeps titles, labels and legends inside the canvas."""
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, dpi=110, layout=layout)


def wrapped(text: str, width_in: float, size_pt: float | None = None) -> str:
    """``text`` with each line broken at spaces to fit ``width_in`` inches at the axes title's font size (a
    title wider than its figure is cut at the edges; session names make compare's titles long)."""
    import textwrap

    import matplotlib
    from matplotlib.font_manager import FontProperties

    size = size_pt or FontProperties(size=matplotlib.rcParams["axes.titlesize"]).get_size_in_points()
    chars = max(10, int(width_in * 72 / (0.6 * size)))
    return "\n".join(textwrap.fill(line, chars, break_on_hyphens=False) for line in text.split("\n"))


def session_style(si: int) -> dict[str, Any]:
    """Line style of session ``si`` in an overlay: the first broad and translucent, later ones thin and dashed
    on top, so identical traces (equal seeds) still show both."""
    color = SESSION_COLORS[si % len(SESSION_COLORS)]
    if si == 0:
        return dict(color=color, lw=2.6, alpha=0.45, ls="-", zorder=2)
    return dict(color=color, lw=1.1, alpha=1.0, ls=(0, (4, 2)) if si == 1 else (0, (1, 1.5)), zorder=3 + si)


def by_frequency(a: SessionAnalysis) -> pd.DataFrame:
    """The per-step table in frequency order (a sweep may run down or repeat frequencies)."""
    t = a.table
    return t.sort_values("frequency_hz", kind="stable") if "frequency_hz" in t else t


def step_frequency(r: StepResult) -> float:
    """The frequency a step was analysed at (measured), else the commanded one."""
    f = r.row.get("analysis_frequency_hz", np.nan)
    return float(f) if np.isfinite(f) else r.frequency_hz


def primary_marker(a: SessionAnalysis) -> str | None:
    """The marker whose path the trajectory grid shows: the foot on the contact rig, a foot on the walker."""
    names: set[str] = set()
    for r in a.steps:
        names.update(r.paths)
    for m in ("foot", "tip", "foot_left", "foot_right"):
        if m in names:
            return m
    return next(iter(sorted(names)), None)
