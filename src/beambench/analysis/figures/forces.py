"""Normal and tangential plate force over a few drive cycles at chosen frequencies (paper Fig. 4b)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import (
    REGIME_NAMES,
    SESSION_COLORS,
    legend_below,
    new_figure,
    session_style,
    step_frequency,
)
from beambench.analysis.path_shape import period_cycles

if TYPE_CHECKING:
    from beambench.analysis.session import SessionAnalysis, StepResult

CONTACT = "#ff7f0e"
PERIOD: dict[str, Any] = dict(
    color="#9467bd", ls=(0, (4, 3)), lw=0.9, alpha=0.7, zorder=0
)  # drive-period marks, not grid-like


@FIGURES.add(
    "forces",
    rigs=("contact",),
    caption="Calibrated normal and tangential plate force over a few drive cycles (paper Fig. 4b). Shaded: "
    "detected contacts; dashed purple: one drive period (1/f) apart. Each column shows the window whose "
    "touchdowns are spaced as the step's regime says (k cycles apart in 1 contact / k cycles); where no window "
    "of the step is, the title says 'irregular here' with the gaps it shows.",
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
    return fig_forces(analyses, path, choose_force_frequencies(analyses, options.force_at))


def choose_force_frequencies(
    analyses: list[SessionAnalysis], wanted: list[float] | None = None, n: int = 3
) -> list[float]:
    """Frequencies for the force-trace figure: the ones asked for (nearest steps), else one per contact regime."""
    a = analyses[0]
    steps = [r for r in a.steps if r.contacts is not None]
    if not steps:
        return []
    have = np.array([r.frequency_hz for r in steps])
    if wanted:
        return sorted({float(have[np.argmin(np.abs(have - w))]) for w in wanted})
    out: list[float] = []
    t = a.table
    for regime in ("1", "1/2", "1/3", "1/4", "2", "continuous"):
        sub = t[t.get("regime", pd.Series(dtype=str)) == regime]
        if len(sub):
            out.append(float(sub["frequency_hz"].iloc[len(sub) // 2]))
        if len(out) == n:
            break
    if not out:
        out = [float(have[len(have) // 2])]
    return sorted(out)


def fig_forces(
    analyses: list[SessionAnalysis], path: Path, frequencies: list[float], cycles: float = 6.0
) -> Path | None:
    """Force traces at ``frequencies``, one column each; None if there are none."""
    if not frequencies:
        return None
    ncol = len(frequencies)
    single = len(analyses) == 1
    fig = new_figure((4.2 * ncol + 0.6, 6.0))
    axes = fig.subplots(2, ncol, sharex="col", squeeze=False)
    for j, f in enumerate(frequencies):
        titles = []
        for si, a in enumerate(analyses):
            r = next((r for r in a.steps if r.frequency_hz == f and r.contacts is not None), None)
            if r is not None and len(r.t_force):
                titles.append(_column(axes[0][j], axes[1][j], r, a.label, None if single else si, cycles))
        if single and titles:
            axes[0][j].set_title(f"{f:g} Hz: {titles[0]}")
        elif titles:
            axes[0][j].set_title(f"{f:g} Hz\n" + "\n".join(titles), fontsize=9)
        axes[1][j].set_xlabel("time (ms)")
        axes[1][j].axhline(0, color="0.3", lw=0.6)
    axes[0][0].set_ylabel("normal force (N)")
    axes[1][0].set_ylabel("tangential force (N)")
    from matplotlib.lines import Line2D

    period = Line2D([], [], **{**PERIOD, "zorder": None}, label="drive period (1/f)")
    if single:
        from matplotlib.patches import Patch

        handles = [
            Patch(color=CONTACT, alpha=0.25, label="contact"),
            Line2D([], [], color="0.5", ls=":", label="contact threshold (normal force)"),
            period,
        ]
    else:
        handles = [
            Line2D([], [], **{**session_style(i), "zorder": None}, label=a.label) for i, a in enumerate(analyses)
        ]
        handles.append(period)
    legend_below(fig, axes, handles=handles)
    fig.suptitle("Plate forces (calibrated)")
    fig.savefig(path)
    return path


def _column(ax_n: Any, ax_t: Any, r: StepResult, label: str, si: int | None, cycles: float) -> str:
    """One step's normal and tangential traces from half a period before its first touchdown; returns the
    title text (regime and contacts per cycle)."""
    fa = step_frequency(r)
    c = r.contacts
    t0 = r.t_force[0]
    reg = str(r.row.get("regime", ""))
    win = ForceWindow(r.t_force[0], [], True)
    if c is not None and c.n_touchdowns:
        win = force_window(np.asarray(c.touchdown_s, float), fa, reg, cycles)
        t0 = max(r.t_force[0], win.start_s)
    sel = (r.t_force >= t0) & (r.t_force <= t0 + cycles / fa)
    tt = (r.t_force[sel] - t0) * 1e3
    style = dict(color=SESSION_COLORS[0], lw=0.9) if si is None else session_style(si)
    ax_n.plot(tt, r.force[sel, 0], **style)
    ax_t.plot(tt, r.force[sel, 1], **style)
    if si is None and c is not None:
        for s, e in zip(c.start_s, c.end_s):
            if e >= t0 and s <= t0 + cycles / fa:
                for ax in (ax_n, ax_t):
                    ax.axvspan((s - t0) * 1e3, (e - t0) * 1e3, color=CONTACT, alpha=0.12, lw=0)
        ax_n.axhline(c.on_n, color="0.5", ls=":", lw=0.8)
    period_ms = 1e3 / fa
    for ax in (ax_n, ax_t):
        ax.grid(False, axis="x")
        for kk in range(int(cycles) + 1):
            ax.axvline(kk * period_ms, **PERIOD)
    ratio = r.row.get("contacts_per_cycle", np.nan)
    odd = "" if win.typical else f"irregular here: contacts {', '.join(f'{g:.1f}' for g in win.gaps)} cycles apart"
    if si is None:
        return f"{REGIME_NAMES.get(reg, reg)} ({ratio:.2f} per cycle)" + (f"\n{odd}" if odd else "")
    return f"{label}: {reg or 'none'} ({ratio:.2f}/cycle)" + (f" · {odd}" if odd else "")


@dataclass(frozen=True)
class ForceWindow:
    """Where a step's force traces start (s, half a period before a touchdown), the gaps between the touchdowns
    in the window (drive cycles) and whether they are those the regime's label promises."""

    start_s: float
    gaps: list[float]
    typical: bool


GAP_TOLERANCE = 0.25  # drive cycles: a gap this close to the label's is typical of it


def force_window(touchdown_s: np.ndarray, f: float, regime: str, cycles: float) -> ForceWindow:
    """The window of ``cycles`` drive cycles whose touchdown gaps are closest to the regime's (k cycles in 1/k,
    one in "1", half in "2"; the time after its last touchdown no longer than a gap, with the tolerance); the
    first touchdown's where the regime promises no gap (irregular, continuous)."""
    expected = {"1": 1.0, "2": 0.5}.get(regime) or (float(period_cycles(regime)) if regime.startswith("1/") else None)
    best: tuple[float, float, list[float]] | None = None
    for td in touchdown_s if expected else touchdown_s[:1]:
        start = td - 0.5 / f
        inside = touchdown_s[(touchdown_s >= start) & (touchdown_s <= start + cycles / f)]
        gaps = [float(g) for g in np.diff(inside) * f]
        if expected is None:
            return ForceWindow(float(start), gaps, True)
        if not gaps:
            continue
        tail = (start + cycles / f - inside[-1]) * f  # cycles after the last touchdown: no contact there
        miss = max([abs(g - expected) for g in gaps] + [tail - expected - GAP_TOLERANCE])
        if best is None or miss < best[0] - 1e-9:
            best = (miss, float(start), gaps)
    if best is None:
        return ForceWindow(float(touchdown_s[0] - 0.5 / f), [], True)
    return ForceWindow(best[1], best[2], best[0] <= GAP_TOLERANCE)
