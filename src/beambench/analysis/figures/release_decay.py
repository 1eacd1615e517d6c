"""The release test: the tip's displacement through the loaded hold, the release and the decay, with the fitted
free response (natural frequency, damping ratio) over the data."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import SESSION_COLORS, new_figure, session_style
from beambench.analysis.release import step_decay
from beambench.common.figures import legend_below

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import SessionAnalysis

AXES = ("x", "y", "z")
AXIS_COLORS = ("#8c564b", "#2ca02c", "#9467bd")
ZOOM_SETTLING = 4.0  # the right panel spans this many settling times after the release


@FIGURES.add(
    "release_decay",
    scenes=lambda s: s.free_decay,
    caption="Release test. Left: the tip markers' mean relative to the clamp, from its rest position, through the "
    "loaded hold, the release (dotted line) and the decay — bold along the loaded deflection, thin per world axis. "
    "Right: the decay after the release with the fitted free response of a second-order system (natural frequency "
    "fₙ, damping ratio ζ; values in the table below).",
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
    fits = [(si, a, f) for si, a in enumerate(analyses) for f in [step_decay(r) for r in a.steps[:1]] if f is not None]
    if not fits:
        return None
    fig = new_figure((12.5, 4.6))
    ax_all, ax_zoom = fig.subplots(1, 2, gridspec_kw=dict(width_ratios=[1.35, 1]))
    single = len(fits) == 1
    for si, a, (d, decay) in fits:
        color = SESSION_COLORS[si % 4]
        sfx = "" if single else f" ({a.label})"
        t_ms = d.t * 1e3
        if single:
            for k, (name, c) in enumerate(zip(AXES, AXIS_COLORS)):
                ax_all.plot(t_ms, d.xyz[:, k], color=c, lw=0.8, alpha=0.8, label=f"{name} (world)")
        line = dict(color=color, lw=1.8) if single else session_style(si)
        ax_all.plot(t_ms, d.along, **line, label="along the loaded deflection" + sfx)
        if not np.isfinite(decay.release_s):
            continue
        for ax in (ax_all, ax_zoom):
            ax.axvline(decay.release_s * 1e3 if ax is ax_all else 0.0, color="0.3", ls=":", lw=1)
        tau = (d.t - decay.release_s) * 1e3
        span = max(ZOOM_SETTLING * decay.settling_ms, 10 * float(np.median(np.diff(t_ms))))
        sel = (tau >= -0.15 * span) & (tau <= span)
        dots = dict(ms=3.5) if single or si else dict(ms=7, alpha=0.45)  # an overlay: the first broad underneath
        ax_zoom.plot(tau[sel], d.along[sel], "o", color=color, ls="", **dots, label="measured" + sfx)
        fine = np.linspace(tau[sel][0], tau[sel][-1], 400)
        text = f"fit: fₙ {decay.natural_frequency_hz:.1f} Hz, ζ {decay.damping_ratio:.2f}"
        fit_line = dict(color="k", lw=1.2) if single else session_style(si)
        ax_zoom.plot(fine, decay(fine / 1e3 + decay.release_s), **fit_line, label=text + sfx)
    ax_all.axhline(0, color="0.6", lw=0.8)
    ax_all.set(
        xlabel="time in the record window (ms)",
        ylabel="tip displacement from rest (mm)",
        title="Loaded hold (until the dotted line), release and decay",
    )
    ax_zoom.axhline(0, color="0.6", lw=0.8)
    ax_zoom.set(xlabel="time after the release (ms)", ylabel="along the loaded deflection (mm)", title="Decay and fit")
    legend_below(fig, [ax_all, ax_zoom], ncol=3)
    fig.savefig(path)
    return path
