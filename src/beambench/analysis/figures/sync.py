"""Clock-sync diagnostics: each sample's receive delay above the fitted device→host clock line, per stream.
Drawn only where there are device clocks to fit: not for sessions whose delays are all flat (the sim stamps
every sample on the host clock exactly, so the figure would be lines at zero)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from beambench.analysis.figures.registry import FIGURES, ReportOptions, any_scene
from beambench.analysis.figures.style import SESSION_COLORS, new_figure
from beambench.common.figures import legend_below

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import SessionAnalysis

FLAT_US = 1.0  # delays spread less than this: nothing to show


def shows_something(a: SessionAnalysis) -> bool:
    """The session has a stream whose receive delays above the clock fit spread by more than ``FLAT_US``."""
    return any(len(r) and float(np.nanmax(r) - np.nanmin(r)) > FLAT_US for r in a.residuals_us.values())


@FIGURES.add(
    "sync",
    scenes=any_scene,
    caption="Clock sync: each sample's receive delay above the fitted device→host clock line (lower envelope).",
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions, max_points: int = 2500) -> Path | None:
    shown = [a for a in analyses if shows_something(a)]
    rows = [(a, n, r) for a in shown for n, r in a.residuals_us.items() if len(r)]
    if not rows:
        return None
    names = sorted({n for _, n, _ in rows})
    fig = new_figure((4.6 * len(names), 3.8))
    axes = fig.subplots(1, len(names), squeeze=False)
    for j, n in enumerate(names):
        ax = axes[0][j]
        for si, a in enumerate(analyses):
            r = a.residuals_us.get(n)
            ts = a.residual_t_s.get(n)
            if a not in shown or r is None or not len(r) or ts is None:
                continue
            idx = np.linspace(0, len(r) - 1, min(max_points, len(r))).astype(int)
            lbl = a.label if len(analyses) > 1 else None
            ax.plot(ts[idx], r[idx] / 1e3, ".", ms=1.5, color=SESSION_COLORS[si % 4], alpha=0.6, label=lbl)
            fit = a.fits.get(n)
            if fit is not None and si == 0:
                ax.set_title(f"{n}: drift {fit.drift_ppm:+.1f} ppm, median delay {fit.residual_median_us / 1e3:.2f} ms")
        ax.set(xlabel="session time (s)", ylabel="receive delay above fit (ms)")
    if len(analyses) > 1:  # one entry per session (every panel has the same sessions)
        legend_below(fig, axes, ncol=len(analyses), markerscale=6)
    fig.savefig(path)
    return path
