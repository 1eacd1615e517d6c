"""Commanded against measured drive frequency (stage marker sine fit; motor encoder speed) and the stage
amplitude; a panel is left out when the session has nothing for it (the walker has no stage marker)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import SESSION_COLORS, by_frequency, new_figure
from beambench.common.figures import legend_below

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import SessionAnalysis


def _has(a: SessionAnalysis, col: str) -> bool:
    return col in a.table and bool(a.table[col].notna().any())


@FIGURES.add(
    "frequency",
    scenes=lambda s: s.driven,
    caption="Commanded against measured drive frequency (stage marker sine fit; motor encoder speed) and, where "
    "there is a stage marker, the stage amplitude.",
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
    sources = [
        (c, name) for c, name in (("measured_frequency_hz", "stage marker"), ("motor_frequency_hz", "motor encoder"))
    ]
    if not any(_has(a, c) for a in analyses for c, _ in sources):
        return None
    amplitude = any(_has(a, "stage_amplitude_mm") for a in analyses)
    n = 3 if amplitude else 2
    fig = new_figure((4.7 * n, 4.3))
    axes = fig.subplots(1, n)
    for si, a in enumerate(analyses):
        t = by_frequency(a)
        c = SESSION_COLORS[si % 4]
        suffix = f" ({a.label})" if len(analyses) > 1 else ""
        f = t["frequency_hz"]
        for (col, name), (mk, line) in zip(sources, (("o", "o-"), ("x", "x--"))):
            if _has(a, col):
                axes[0].plot(f, t[col], mk, color=c, ms=5, label=name + suffix)
                axes[1].plot(f, t[col] - f, line, color=c, ms=4, lw=0.8, label=name + suffix)
        if amplitude and _has(a, "stage_amplitude_mm"):
            axes[2].plot(f, t["stage_amplitude_mm"], "o-", color=c, ms=4, lw=0.8, label="measured" + suffix)
            cmd = t.get("commanded_amplitude_mm")
            if cmd is not None and cmd.notna().any():
                axes[2].axhline(float(cmd.dropna().iloc[0]), color=c, ls="--", lw=1, label="commanded" + suffix)
    lim = [0, max(float(a.table["frequency_hz"].max()) for a in analyses) * 1.05]
    axes[0].plot(lim, lim, color="0.6", lw=1, label="measured = commanded")
    axes[0].set(xlabel="commanded frequency (Hz)", ylabel="measured frequency (Hz)", title="Drive frequency")
    axes[1].axhline(0, color="0.6", lw=1)
    axes[1].set(xlabel="commanded frequency (Hz)", ylabel="measured − commanded (Hz)", title="Frequency error")
    if amplitude:
        axes[2].set(
            xlabel="commanded frequency (Hz)",
            ylabel="stage amplitude (mm)",
            title="Stage amplitude (A of x = A·sin 2πft)",
        )
    legend_below(fig, axes, ncol=6)
    fig.savefig(path)
    return path
