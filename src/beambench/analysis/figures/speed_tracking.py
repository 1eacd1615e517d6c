"""Speed tracking (``track:`` sessions): target and measured speed vs time, the commanded frequency below.

:func:`draw` (registered as ``tracking``) draws every session that has tracking results side by side (e.g.
feed-forward alone vs with feedback, with ``beambench compare``), each a column of two panels.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.speed_tracking import TrackResult

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import SessionAnalysis

KEY = "tracking"
CAPTION = "Speed tracking: target and measured body speed (shaded: ±tolerance after settling), commanded frequency"


@FIGURES.add(KEY, scenes=lambda s: s.walks, caption=CAPTION)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
    """The figure for the sessions that have tracking results; None if none has (a sweep)."""
    results = [a.track for a in analyses if a.track is not None]
    if not results:
        return None
    return draw_tracking(results, [a.label for a in analyses if a.track is not None], path)


def draw_tracking(results: list[TrackResult], titles: list[str], path: Path) -> Path:
    """Columns of (speed, frequency) panels, one per result."""
    from matplotlib.figure import Figure

    n = len(results)
    fig = Figure(figsize=(5.2 * n + 0.6, 5.6), dpi=110, layout="constrained")
    axes = fig.subplots(2, n, sharex="col", height_ratios=[2.2, 1], squeeze=False)
    for j, (r, title) in enumerate(zip(results, titles)):
        ax, axf = axes[0, j], axes[1, j]
        for k, ((a, s, b), seg) in enumerate(zip(r.bounds, r.segments)):
            v, tol = seg["target_speed_mm_s"], seg["tolerance_mm_s"]
            ax.fill_between([s, b], v - tol, v + tol, color="0.85", lw=0, label="tolerance" if k == 0 else None)
            ax.axvline(a, color="0.7", lw=0.6, ls=":")
            axf.axvline(a, color="0.7", lw=0.6, ls=":")
            ok = seg["speed_error_rms_mm_s"] <= tol
            ax.text(
                (a + b) / 2,
                0.98,
                f"{seg['speed_error_rms_mm_s']:.1f}",
                transform=ax.get_xaxis_transform(),
                ha="center",
                va="top",
                fontsize=8,
                color="tab:green" if ok else "tab:red",
            )
        ax.step(r.t, r.target, where="post", color="k", lw=1.2, label="target")
        ax.plot(r.speed_t, r.speed, color="tab:blue", lw=1.0, label="measured (0.3 s window)")
        lost = r.mode != 0
        lost &= r.mode != 2
        if lost.any():
            ax.plot(r.t[lost], np.zeros(lost.sum()), "|", color="tab:red", label="mocap lost")
        ax.axhline(0, color="0.5", lw=0.5)
        ax.set_ylabel("speed (mm/s)")
        ax.set_title(f"{title}\n(numbers: RMS error after settling, mm/s)", fontsize=9)
        axf.plot(r.t, r.frequency, color="tab:orange", lw=1.0, label="commanded")
        axf.plot(r.t, r.feedforward, color="0.4", lw=0.8, ls="--", label="feed-forward")
        axf.set_ylabel("drive (Hz)")
        axf.set_xlabel("time (s)")
    seen: dict[str, Any] = {}
    for a in axes[:, 0]:  # one legend below the panels (inside, it hides the traces)
        for h, label in zip(*a.get_legend_handles_labels()):
            seen.setdefault(label, h)
    fig.legend(list(seen.values()), list(seen), loc="outside lower center", ncol=min(3 * n, len(seen)), fontsize=8)
    fig.savefig(path)
    return path
