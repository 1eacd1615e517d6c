"""Normal and tangential plate force over a few drive cycles at chosen frequencies (paper Fig. 4b)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from beambench.acquisition.forces.contact_events import ContactParams, runs
from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import REGIME_NAMES, SESSION_COLORS, new_figure, session_style, step_frequency
from beambench.analysis.path_shape import period_cycles
from beambench.common.figures import legend_below

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import SessionAnalysis, StepResult

CONTACT = "#ff7f0e"
TOUCHDOWN = "#d95f02"
MERGED = ContactParams().min_flight_fraction  # the analysis's: flights shorter than this share of a period merge
DIP = "0.35"
PERIOD: dict[str, Any] = dict(
    color="#9467bd", ls=(0, (4, 3)), lw=0.9, alpha=0.7, zorder=0
)  # drive-period marks, not grid-like


@FIGURES.add(
    "forces",
    scenes=lambda s: s.plate,
    caption="Calibrated normal and tangential plate force over a few drive cycles (paper Fig. 4b). Shaded: "
    "detected contacts; ▼ each counted touchdown (the contacts the title counts); ◇ a dip below the contact "
    f"threshold shorter than {MERGED:.0%} of a drive period, which the contact detection merges into the contact around "
    "it (a chattering sole, not a lift-off: steps.csv counts flights longer than that only); dashed purple: one "
    "drive period (1/f) apart. Each column shows the window whose touchdowns are spaced as the step's regime says "
    "(k cycles apart in 1 contact / k cycles); where no window of the step is, the title says 'irregular here' "
    "with the gaps it shows.",
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
    fig = new_figure((max(4.2 * ncol + 0.6, 7.5), 6.0))  # at least the legend's width
    axes = fig.subplots(2, ncol, sharex="col", squeeze=False)
    drawn: list[ForcePanel] = []
    for j, f in enumerate(frequencies):
        titles = []
        for si, a in enumerate(analyses):
            r = next((r for r in a.steps if r.frequency_hz == f and r.contacts is not None), None)
            if r is not None and len(r.t_force):
                title, panel = _column(axes[0][j], axes[1][j], r, a.label, None if single else si, cycles)
                titles.append(title)
                drawn.append(panel)
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

        handles: list[Patch | Line2D] = [Patch(color=CONTACT, alpha=0.25, label="contact")]
        if any(p.touchdowns_ms for p in drawn):
            handles.append(Line2D([], [], color=TOUCHDOWN, marker="v", ls="", label="touchdown (counted)"))
        if any(p.merged_dips_ms for p in drawn):
            dip = f"dip merged: < {MERGED:.0%} of a period"
            handles.append(Line2D([], [], color=DIP, marker="D", mfc="none", ls="", label=dip))
        handles += [Line2D([], [], color="0.5", ls=":", label="contact threshold (normal force)"), period]
    else:
        handles = [
            Line2D([], [], **{**session_style(i), "zorder": None}, label=a.label) for i, a in enumerate(analyses)
        ]
        handles.append(period)
    legend_below(fig, axes, handles=handles)
    fig.suptitle("Plate forces (calibrated)")
    fig.savefig(path)
    return path


@dataclass(frozen=True)
class ForcePanel:
    """What one step's column shows, in ms from the trace's start: the traces, the detected contacts (merged, clipped
    to the trace), the counted touchdowns in it, the dips below the contact threshold that were merged into a
    contact (each gap shorter than ``min_flight_ms``; gaps closer than that together are one dip), the threshold and
    the window chosen."""

    t_ms: np.ndarray
    normal_n: np.ndarray
    tangential_n: np.ndarray
    contacts_ms: list[tuple[float, float]]
    touchdowns_ms: list[float]
    merged_dips_ms: list[tuple[float, float]]
    threshold_n: float
    min_flight_ms: float
    window: ForceWindow


def force_panel(r: StepResult, cycles: float, min_flight_fraction: float | None = None) -> ForcePanel:
    """One step's ``cycles`` drive cycles of force from half a period before a touchdown typical of its regime
    (:func:`force_window`), with its contacts, touchdowns and merged dips (``min_flight_fraction`` of a period:
    the analysis's, by default)."""
    fa = step_frequency(r)
    c = r.contacts
    reg = str(r.row.get("regime", ""))
    win = ForceWindow(float(r.t_force[0]) if len(r.t_force) else 0.0, [], True)
    if c is not None and c.n_touchdowns:
        win = force_window(np.asarray(c.touchdown_s, float), fa, reg, cycles)
    t0 = max(float(r.t_force[0]), win.start_s) if len(r.t_force) else win.start_s
    sel = (r.t_force >= t0) & (r.t_force <= t0 + cycles / fa)
    t = r.t_force[sel]
    fraction = ContactParams().min_flight_fraction if min_flight_fraction is None else min_flight_fraction
    contacts: list[tuple[float, float]] = []
    touchdowns: list[float] = []
    dips: list[tuple[float, float]] = []
    if c is not None and len(t):
        lo, hi = float(t[0]), float(t[-1])
        for s, e, td in zip(c.start_s, c.end_s, c.touchdown):
            if e > lo and s < hi:
                contacts.append(((max(s, lo) - t0) * 1e3, (min(e, hi) - t0) * 1e3))
                if td and lo <= s <= hi:
                    touchdowns.append((s - t0) * 1e3)
        on = c.mask[sel] if len(c.mask) == len(r.t_force) else np.ones(len(t), bool)
        inside = np.zeros(len(t), bool)
        for s, e in zip(c.start_s, c.end_s):
            inside |= (t >= s) & (t < e)
        starts, ends = runs(inside & ~on)
        t_next = np.append(t, t[-1])
        dips = _episodes([(t[a], t_next[b]) for a, b in zip(starts, ends)], fraction / fa)
        dips = [((a - t0) * 1e3, (b - t0) * 1e3) for a, b in dips]
    return ForcePanel(
        (t - t0) * 1e3,
        r.force[sel, 0],
        r.force[sel, 1],
        contacts,
        touchdowns,
        dips,
        c.on_n if c is not None else float("nan"),
        fraction * 1e3 / fa,
        win,
    )


def _episodes(gaps: list[tuple[float, float]], within_s: float) -> list[tuple[float, float]]:
    """Gaps below the threshold closer together than ``within_s`` as one dip (a chattering sole crosses the
    threshold several times in one dip of the force)."""
    out: list[tuple[float, float]] = []
    for a, b in gaps:
        if out and a - out[-1][1] < within_s:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    return out


def _column(ax_n: Any, ax_t: Any, r: StepResult, label: str, si: int | None, cycles: float) -> tuple[str, ForcePanel]:
    """One step's normal and tangential traces from half a period before its first touchdown; returns the
    title text (regime, contacts per cycle, and the touchdowns and merged dips drawn) and what was drawn."""
    fa = step_frequency(r)
    p = force_panel(r, cycles)
    reg = str(r.row.get("regime", ""))
    style = dict(color=SESSION_COLORS[0], lw=0.9) if si is None else session_style(si)
    ax_n.plot(p.t_ms, p.normal_n, **style)
    ax_t.plot(p.t_ms, p.tangential_n, **style)
    if si is None and r.contacts is not None:
        for s, e in p.contacts_ms:
            for ax in (ax_n, ax_t):
                ax.axvspan(s, e, color=CONTACT, alpha=0.12, lw=0)
        ax_n.axhline(p.threshold_n, color="0.5", ls=":", lw=0.8)
        if p.touchdowns_ms:  # above the trace (unclipped: an empty unclipped line would upset the layout)
            top = ax_n.get_xaxis_transform()
            n = len(p.touchdowns_ms)
            ax_n.plot(p.touchdowns_ms, [1.0] * n, "v", color=TOUCHDOWN, ms=7, transform=top, clip_on=False)
        if p.merged_dips_ms:
            mids = [(a + b) / 2 for a, b in p.merged_dips_ms]
            ax_n.plot(mids, [p.threshold_n] * len(mids), "D", mfc="none", mec=DIP, ms=4.5, mew=1.0)
    period_ms = 1e3 / fa
    for ax in (ax_n, ax_t):
        ax.grid(False, axis="x")
        for kk in range(int(cycles) + 1):
            ax.axvline(kk * period_ms, **PERIOD)
    ratio = r.row.get("contacts_per_cycle", np.nan)
    win = p.window
    odd = "" if win.typical else f"irregular here: contacts {', '.join(f'{g:.1f}' for g in win.gaps)} cycles apart"
    if si is None:
        n = len(p.touchdowns_ms)
        seen = f"{n} ▼ touchdown{'' if n == 1 else 's'}" if n else "no touchdown here"
        if p.merged_dips_ms:
            seen += f", {len(p.merged_dips_ms)} ◇ dips < {p.min_flight_ms:.1f} ms merged"
        return f"{REGIME_NAMES.get(reg, reg)} ({ratio:.2f} per cycle)\n{seen}" + (f"\n{odd}" if odd else ""), p
    return f"{label}: {reg or 'none'} ({ratio:.2f}/cycle)" + (f" · {odd}" if odd else ""), p


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
