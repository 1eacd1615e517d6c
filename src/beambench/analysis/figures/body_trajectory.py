"""The walker's body along the slider through each step's record window, one line per step, coloured by the
drive frequency."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import SESSION_COLORS, new_figure

if TYPE_CHECKING:
    from beambench.analysis.session import SessionAnalysis


@FIGURES.add(
    "body_trajectory",
    rigs=("walker",),
    caption="The body marker's forward position through each step's record window, from where the window "
    "starts: one line per step, coloured by the drive frequency. A straight line is a steady speed (its slope is "
    "the walking-speed figure's point); a wavy one, a gait that surges and stalls within the window.",
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
    import matplotlib as mpl

    runs = [(a, [r for r in a.steps if len(r.body_x_mm) > 2]) for a in analyses]
    runs = [(a, steps) for a, steps in runs if steps]
    if not runs:
        return None
    fmax = max(r.frequency_hz for _, steps in runs for r in steps)
    fmin = min(r.frequency_hz for _, steps in runs for r in steps)
    norm = mpl.colors.Normalize(vmin=fmin, vmax=max(fmax, fmin + 1e-9))
    cmap = mpl.colormaps["viridis"]
    fig = new_figure((8.5 if len(runs) == 1 else 5.2 * len(runs), 4.8))
    axes = fig.subplots(1, len(runs), sharey=True, squeeze=False)[0]
    for ax, (si, (a, steps)) in zip(axes, enumerate(runs)):
        for r in steps:
            x = r.body_x_mm - np.nanmedian(r.body_x_mm[: max(3, len(r.body_x_mm) // 50)])
            ax.plot(r.body_t, x, color=cmap(norm(r.frequency_hz)), lw=0.9)
        ax.axhline(0, color="0.3", lw=0.8)
        ax.set(xlabel="time in the record window (s)", title=a.label if len(runs) > 1 else "Body along the slider")
        if len(runs) > 1:
            ax.title.set_color(SESSION_COLORS[si % 4])
    axes[0].set_ylabel("forward displacement (mm, + forward)")
    bar = fig.colorbar(mpl.cm.ScalarMappable(norm=norm, cmap=cmap), ax=list(axes), pad=0.02)
    bar.set_label("drive frequency (Hz)")
    fig.savefig(path)
    return path
