"""Foot velocity along the plate at touchdown and the mean tangential force, against frequency (paper Fig. 4)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from beambench.acquisition.forces.contact_events import REGIME_ORDER
from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import (
    REGIME_COLORS,
    REGIME_NAMES,
    SESSION_COLORS,
    SESSION_MARKERS,
    by_frequency,
    new_figure,
)
from beambench.common.figures import legend_below

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import SessionAnalysis


@FIGURES.add(
    "contact_direction",
    scenes=lambda s: s.plate,
    caption="Foot velocity along the plate just before touchdown and the mean tangential force while in contact "
    "(paper Fig. 4).",
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
    tabs = [
        (a, by_frequency(a))
        for a in analyses
        if "mean_tangential_n" in a.table and a.table["mean_tangential_n"].notna().any()
    ]
    if not tabs:
        return None
    fig = new_figure((12, 4.3))
    axes = fig.subplots(1, 2, sharex=True)
    single = len(tabs) == 1
    for si, (a, t) in enumerate(tabs):
        f = t["frequency_hz"]
        colors: Any = [REGIME_COLORS.get(str(r), "0.5") for r in t["regime"]] if single else SESSION_COLORS[si % 4]
        line = "0.75" if single else SESSION_COLORS[si % 4]
        lbl = None if single else a.label
        for ax, col in ((axes[0], "touchdown_velocity_mm_s"), (axes[1], "mean_tangential_n")):
            if col not in t:
                continue
            ax.plot(f, t[col], "-", color=line, lw=0.8, zorder=1)
            ax.scatter(f, t[col], c=colors, s=30, zorder=2, marker=SESSION_MARKERS[si % 4], label=lbl)
    for ax in axes:
        ax.axhline(0, color="0.3", lw=0.8)
        ax.set_xlabel("drive frequency (Hz)")
    axes[0].set(ylabel="foot velocity along drive axis (mm/s)", title="Direction of motion at touchdown (vs plate)")
    axes[1].set(ylabel="mean tangential force in contact (N)", title="Tangential force")
    if single:
        from matplotlib.lines import Line2D

        present = [r for r in REGIME_ORDER if r in set(tabs[0][1]["regime"])]
        handles = [
            Line2D([], [], ls="", marker="o", color=REGIME_COLORS[r], label=REGIME_NAMES.get(r, r)) for r in present
        ]
        legend_below(fig, axes, ncol=6, handles=handles)
    else:
        legend_below(fig, axes)
    fig.savefig(path)
    return path
