"""Contact frequency against the drive frequency, coloured by regime, with f, f/2, f/3 guides (paper Fig. 1b)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

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
)

if TYPE_CHECKING:
    from beambench.analysis.session import SessionAnalysis


@FIGURES.add(
    "contact_frequency",
    rigs=("contact",),
    caption="Touchdowns per second against the drive frequency (paper Fig. 1b). Guides at f, f/2, f/3. "
    "Hollow points at 0: continuous contact or none.",
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
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
        present = [r for r in REGIME_ORDER if r in set(t["regime"])] + sorted(set(t["regime"]) - set(REGIME_ORDER))
        for regime in present:
            sub = t[t["regime"] == regime]
            hollow = regime in ("none", "continuous", "")
            color = REGIME_COLORS.get(regime, "0.5")
            ax.scatter(
                sub["frequency_hz"],
                sub["contact_frequency_hz"].fillna(0.0),
                s=36,
                marker="o",
                facecolors="none" if hollow else color,
                edgecolors=color,
                linewidths=1.2,
                label=REGIME_NAMES.get(regime, f"{regime} contacts / cycle"),
                zorder=3,
            )
    ax.set_xlabel("input (drive) frequency (Hz)")
    ax.set_ylabel("contact frequency (Hz)")
    ax.set_xlim(0, max(fmax, 1.0) * 1.12)
    ax.set_ylim(bottom=-0.02 * max(fmax, 1.0))
    ax.set_title(
        "Contact frequency vs input frequency" + ("" if single else " — " + " vs ".join(a.label for a, _ in tables))
    )
    legend_below(fig, ax)
    fig.savefig(path)
    return path
