"""The release fit's figure: measured vs fitted tip markers (x and z against time, and the x–z path), in the
report's shared style."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from beambench.common.figures import legend_below, new_figure, shared_style

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from beambench.studies.fit.release import FitResult


def plot_fit(results: Sequence[FitResult], path: str | Path, title: str = "") -> Path:
    """Measured vs fitted tip-marker paths: x and z against time, and the x–z path (mm), in the report's style."""
    with shared_style():
        fig = fit_figure(results, title)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=120)
    return path


def fit_figure(results: Sequence[FitResult], title: str = "") -> Figure:
    """The fit figure (drawn under the caller's style): one legend below the panels, where it hides no trace."""
    import matplotlib

    r0 = results[0]
    fig = new_figure(figsize=(14, 4.8), layout="constrained")
    axes = fig.subplots(1, 3)
    colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    t_ms = r0.t * 1e3
    styles = ["-", "--", ":"]
    for m, name in enumerate(r0.names):
        c = colors[m % len(colors)]
        meas = r0.measured[:, m] * 1e3
        axes[0].plot(t_ms, meas[:, 0], ".", ms=3, color=c, label=f"{name} measured")
        axes[1].plot(t_ms, meas[:, 2], ".", ms=3, color=c)
        axes[2].plot(meas[:, 0], meas[:, 2], ".", ms=3, color=c)
        for k, r in enumerate(results):
            fit = r.fitted[:, m] * 1e3
            lab = f"{name} {r.model} ({r.rms_mm:.2f} mm)"
            axes[0].plot(t_ms, fit[:, 0], styles[k % 3], color=c, lw=1.2, label=lab)
            axes[1].plot(t_ms, fit[:, 2], styles[k % 3], color=c, lw=1.2)
            axes[2].plot(fit[:, 0], fit[:, 2], styles[k % 3], color=c, lw=1.2)
    axes[0].set(xlabel="time from release (ms)", ylabel="x (mm)", title="tip markers: x (drive axis)")
    axes[1].set(xlabel="time from release (ms)", ylabel="z (mm)", title="tip markers: z (up)")
    axes[2].set(xlabel="x (mm)", ylabel="z (mm)", title="tip paths (x–z)")
    axes[2].set_aspect("equal", adjustable="datalim")
    legend_below(fig, axes, ncol=len(r0.names))
    fig.suptitle(title or "Release test: measured vs fitted tip markers")
    return fig
