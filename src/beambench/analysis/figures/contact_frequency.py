"""Contact frequency against the drive frequency, coloured by regime, with f, f/2, f/3 guides (paper Fig. 1b)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from beambench.analysis.contact import REGIME_ORDER
from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import (
    REGIME_COLORS,
    REGIME_NAMES,
    SESSION_MARKERS,
    by_frequency,
    legend_below,
    new_figure,
    session_style,
    wrapped,
)

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from beambench.analysis.session_analysis import SessionAnalysis


@FIGURES.add(
    "contact_frequency",
    rigs=("contact",),
    caption="Touchdowns per second against the drive frequency (paper Fig. 1b). Guides at f, f/2, f/3. "
    "Hollow points at 0: continuous contact or none. A sweep both ways: ▲ up, ▼ down, red bands where the branches "
    "differ (hysteresis: regime, or contacts per cycle beyond noise); repeats: every repeat a point, "
    "their mean ± 1 std as a bar; "
    "× reference steps.",
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
    fig = contact_frequency_figure(analyses)
    if fig is None:
        return None
    fig.savefig(path)
    return path


def contact_frequency_figure(analyses: list[SessionAnalysis]) -> Figure | None:
    """Contact against drive frequency of each session; None if no session has contact frequencies."""
    tables = [(a, by_frequency(a)) for a in analyses if "contact_frequency_hz" in a.table]
    if not tables:
        return None
    fig = new_figure((7.5, 5.0))
    ax = fig.subplots()
    fmax = max(float(t["frequency_hz"].max()) for _, t in tables)
    xs = np.linspace(0, fmax * 1.05, 50)
    for k, ls in ((1, "-"), (2, "--"), (3, ":")):
        ax.plot(xs, xs / k, color="0.6", ls=ls, lw=1)
        ax.text(xs[-1], xs[-1] / k, " f" if k == 1 else f" f/{k}", va="center", color="0.4")
    single = len(tables) == 1
    for si, (a, t) in enumerate(tables):
        y = t["contact_frequency_hz"].fillna(0.0)
        if not single:  # one colour and marker per session; later sessions hollow and dashed on top
            st = session_style(si)
            c = st["color"]
            ax.plot(
                t["frequency_hz"],
                y,
                color=c,
                lw=st["lw"],
                ls=st["ls"],
                alpha=0.8,
                marker=SESSION_MARKERS[si % 4],
                ms=9 if si == 0 else 5,
                mfc=c if si == 0 else "none",
                mec=c,
                label=a.label,
                zorder=st["zorder"],
            )
            continue
        _branches(ax, t)
    ax.set_xlabel("input (drive) frequency (Hz)")
    ax.set_ylabel("contact frequency (Hz)")
    ax.set_xlim(0, max(fmax, 1.0) * 1.12)
    ax.set_ylim(bottom=-0.02 * max(fmax, 1.0))
    names = "" if single else "\n" + " vs ".join(a.label for a, _ in tables)
    ax.set_title(wrapped("Contact frequency vs input frequency" + names, float(fig.get_figwidth()) - 0.8))
    legend_below(fig, ax)
    return fig


def _branches(ax: Any, t: pd.DataFrame) -> None:
    """One session: every step a point coloured by its regime, ▲/▼ by sweep direction, a repeated frequency's
    mean ± std,
    hysteresis bands, reference steps as ×."""
    kind = t["kind"] if "kind" in t else pd.Series("sweep", index=t.index)
    direction = t["direction"] if "direction" in t else pd.Series("up", index=t.index)
    sweep = t[kind == "sweep"].assign(direction=direction, y=t["contact_frequency_hz"].fillna(0.0))
    ref = t[kind == "reference"]
    both = set(sweep["direction"]) >= {"up", "down"}
    if "hysteresis" in sweep:
        flagged = sorted(set(sweep.loc[sweep["hysteresis"].astype(bool), "frequency_hz"]))
        fs = np.unique(sweep["frequency_hz"])
        half = 0.35 * float(np.min(np.diff(fs))) if len(fs) > 1 else 0.5
        for i, f in enumerate(flagged):
            ax.axvspan(f - half, f + half, color="#d62728", alpha=0.12, lw=0, label="hysteresis" if i == 0 else None)
    seen: set[str] = set()
    for d, g in sweep.groupby("direction", sort=False):
        stat = g.groupby("frequency_hz")["y"].agg(["mean", "std", "size"])
        if both:
            ax.plot(stat.index, stat["mean"], color="0.55", lw=0.8, ls="-" if d == "up" else "--", zorder=2)
        marker = ("^" if d == "up" else "v") if both else "o"
        if (stat["size"] > 1).any():  # repeats: the mean ± 1 std as a bar; every repeat its own point
            rep = stat[stat["size"] > 1]
            ax.errorbar(rep.index, rep["mean"], yerr=rep["std"], fmt="_", ms=10, color="0.25", lw=0.9, capsize=2)
        regimes = set(g["regime"].astype(str))
        present = [r for r in REGIME_ORDER if r in regimes] + sorted(regimes - set(REGIME_ORDER))
        for regime in present:
            sub = g[g["regime"].astype(str) == regime]
            hollow = regime in ("none", "continuous", "")
            color = REGIME_COLORS.get(regime, "0.5")
            ax.scatter(
                sub["frequency_hz"],
                sub["y"],
                s=36,
                marker=marker,
                facecolors="none" if hollow else color,
                edgecolors=color,
                linewidths=1.2,
                label=None if regime in seen else REGIME_NAMES.get(regime, f"{regime} contacts / cycle"),
                zorder=3,
            )
            seen.add(regime)
    if both:
        for d, m, ls in (("up", "^", "-"), ("down", "v", "--")):
            ax.plot([], [], marker=m, ls=ls, color="0.45", mfc="none", lw=0.8, label=f"sweep {d}")
    if len(ref):
        ax.scatter(
            ref["frequency_hz"],
            ref["contact_frequency_hz"].fillna(0.0),
            marker="x",
            color="0.35",
            s=30,
            label="reference steps",
            zorder=4,
        )
