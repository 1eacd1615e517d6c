"""Walker body speed (signed, mm/s) against drive frequency, with the paper's two reported points (Fig. 5)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import SESSION_COLORS, SESSION_MARKERS, by_frequency, new_figure
from beambench.common.figures import legend_below

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import SessionAnalysis

PAPER_WALKER = [(23.0, -35.7), (65.0, 156.3)]  # Sec. IV-B, mm/s


@FIGURES.add(
    "walking_speed",
    scenes=lambda s: s.walks,
    caption="Walker body speed from the body marker (least-squares slope over the record window).",
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
    tabs = [
        (a, by_frequency(a))
        for a in analyses
        if "body_speed_mm_s" in a.table and a.table["body_speed_mm_s"].notna().any()
    ]
    if not tabs:
        return None
    fig = new_figure((7.5, 4.6))
    ax = fig.subplots()
    for si, (a, t) in enumerate(tabs):
        err = t.get("body_speed_stderr_mm_s")
        ax.errorbar(
            t["frequency_hz"],
            t["body_speed_mm_s"],
            yerr=None if err is None else err,
            fmt=SESSION_MARKERS[si % 4] + "-",
            color=SESSION_COLORS[si % 4],
            ms=4,
            lw=1,
            capsize=2,
            label=a.label,
        )
    ax.axhline(0, color="0.3", lw=0.8)
    px, py = zip(*PAPER_WALKER)
    ax.plot(px, py, "*", ms=13, mfc="none", mec="k", label="paper (Sec. IV-B)")
    ax.set(xlabel="drive frequency (Hz)", ylabel="body speed (mm/s, + forward)", title="Walking speed vs frequency")
    legend_below(fig, ax)
    fig.savefig(path)
    return path
