"""Contact frequency against the drive frequency, coloured by regime, with f, f/2, f/3 guides and the paper's
measured regimes beside them (paper Fig. 1b, Sec. IV-A), so where the session agrees with the paper and where it
does not both show."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from beambench.acquisition.forces.contact_events import REGIME_ORDER
from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import (
    REGIME_COLORS,
    REGIME_NAMES,
    SESSION_MARKERS,
    by_frequency,
    new_figure,
    session_style,
    wrapped,
)
from beambench.common.figures import legend_below

PAPER = "#bcbd22"  # the paper's measured regimes

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from beambench.analysis.session_analysis import SessionAnalysis


@FIGURES.add(
    "contact_frequency",
    scenes=lambda s: s.plate,
    caption="Touchdowns per second against the drive frequency (paper Fig. 1b). Guides at f, f/2, f/3. "
    "Broad pale bands: the paper's measured regimes (Sec. IV-A: continuous contact below 18 Hz, one contact per "
    "cycle to 26 Hz, one per two cycles to 38 Hz, one per three to 44 Hz); the title counts the steps whose "
    "regime is the paper's at their frequency. "
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


@dataclass(frozen=True)
class PaperRegime:
    """One of the paper's measured contact regimes: contacts per drive cycle (0: continuous contact) over a band
    of drive frequencies (Hz)."""

    from_hz: float
    to_hz: float
    per_cycle: float
    label: str


# Paper Sec. IV-A (and Fig. 1b): the foot never leaves the plate below 18 Hz; the contact frequency follows f
# to 26 Hz, drops to f/2 at 26 Hz and to f/3 at 38 Hz; the measured range ends at 44 Hz.
PAPER_REGIMES = (
    PaperRegime(0.0, 18.0, 0.0, "continuous"),
    PaperRegime(18.0, 26.0, 1.0, "1"),
    PaperRegime(26.0, 38.0, 0.5, "1/2"),
    PaperRegime(38.0, 44.0, 1 / 3, "1/3"),
)


def paper_regime(frequency_hz: float) -> str:
    """The paper's regime at a drive frequency (the higher band at a shared edge), "" outside its range."""
    for band in reversed(PAPER_REGIMES):
        if band.from_hz <= frequency_hz <= band.to_hz:
            return band.label
    return ""


def paper_agreement(t: pd.DataFrame) -> tuple[int, int]:
    """Sweep steps whose regime is the paper's at their frequency, of the steps inside the paper's range."""
    if "regime" not in t or "frequency_hz" not in t:
        return 0, 0
    expected = t["frequency_hz"].astype(float).map(paper_regime)
    inside = expected != ""
    return int((t["regime"].astype(str)[inside] == expected[inside]).sum()), int(inside.sum())


def _paper_bands(ax: Any, fmax: float) -> None:
    """The paper's regimes as broad pale bands along f, f/2, f/3 (and along 0 where the contact is continuous)."""
    for i, band in enumerate(PAPER_REGIMES):
        hi = min(band.to_hz, fmax)
        if hi <= band.from_hz:
            continue
        xs = np.array([band.from_hz, hi])
        ax.plot(
            xs,
            xs * band.per_cycle,
            color=PAPER,
            lw=9,
            alpha=0.35,
            solid_capstyle="butt",
            zorder=1,
            label="paper (Sec. IV-A): regime measured" if i == 0 else None,
        )
    for edge in sorted({b.from_hz for b in PAPER_REGIMES if 0 < b.from_hz <= fmax}):
        ax.axvline(edge, color=PAPER, lw=0.8, ls=(0, (2, 2)), zorder=1)


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
    _paper_bands(ax, fmax * 1.05)
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
    agree = [paper_agreement(_sweep_rows(t)) for _, t in tables]
    said = "; ".join(f"{n} of {m}" for n, m in agree if m)
    if said:
        said = f"\nthe paper's regime at {said} steps of its range (≤ {PAPER_REGIMES[-1].to_hz:g} Hz)"
    ax.set_title(wrapped("Contact frequency vs input frequency" + names + said, float(fig.get_figwidth()) - 0.8))
    legend_below(fig, ax)
    return fig


def _sweep_rows(t: pd.DataFrame) -> pd.DataFrame:
    """The sweep's steps (reference steps repeat one frequency and would weigh it many times)."""
    return t[t["kind"] == "sweep"] if "kind" in t else t


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
