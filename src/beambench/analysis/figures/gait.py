"""Walker gait from the mocap: when each foot is on the ground (its height within a noise margin of the ground),
over a few cycles at chosen frequencies, and each foot's duty factor against the drive frequency."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import FOOT_COLORS, marker_name, new_figure, session_style, step_frequency
from beambench.analysis.walking import STANCE_MM, Stance, foot_stance, ground_level
from beambench.common.figures import legend_below

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from beambench.analysis.session_analysis import SessionAnalysis, StepResult

SHOW_HZ = (23.0, 65.0)  # the paper's two walking points (Sec. IV-B), then the fastest step
CYCLES = 4


@FIGURES.add(
    "gait",
    scenes=lambda s: s.walks,
    caption=f"Gait from the mocap. Top: each foot's height above the ground over {CYCLES} drive cycles at the "
    "paper's two walking frequencies and the fastest step; under it, a row per foot with bars where the foot "
    "is on the ground (within "
    f"{STANCE_MM:g} mm of the ground, taken as the foot's low heights over the session). Bottom: the share of "
    "each step's record window each foot spends on the ground (duty factor); at a few mocap frames per drive "
    "cycle (360 frames/s at 65 Hz: 5.5) a stance is one or two frames long, so the bars and the duty factor are "
    "as coarse as the frame interval.",
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
    fig = gait_figure(analyses)
    if fig is None:
        return None
    fig.savefig(path)
    return path


def gait_figure(analyses: list[SessionAnalysis]) -> Figure | None:
    """The gait figure (None without feet): foot heights, stance strips and the duty factor per step."""
    feet_of = {id(a): _feet(a) for a in analyses}
    if not any(feet_of.values()):
        return None
    a0 = next(a for a in analyses if feet_of[id(a)])
    shown = _chosen_steps(a0)
    fig = new_figure((4.3 * max(len(shown), 2), 8.0))
    grid = fig.add_gridspec(3, max(len(shown), 1), height_ratios=[1.1, 0.32, 1])
    ground = {id(a): _grounds(a, feet_of[id(a)]) for a in analyses}
    first = None
    for j, r in enumerate(shown):
        ax = fig.add_subplot(grid[0, j], sharey=first)
        first = first or ax
        ax_s = fig.add_subplot(grid[1, j], sharex=ax)
        _timing(ax, ax_s, a0, r, feet_of[id(a0)], ground[id(a0)])
    ax_d = fig.add_subplot(grid[2, :])
    for si, a in enumerate(analyses):
        for foot in feet_of[id(a)]:
            f, duty = _duty(a, foot, ground[id(a)][foot])
            lbl = marker_name(foot) + ("" if len(analyses) == 1 else f" ({a.label})") + ": duty factor"
            if len(analyses) == 1:
                ls = "-" if foot.endswith("left") else "--"
                ax_d.plot(f, duty, ls, marker="o", ms=3, lw=1, color=FOOT_COLORS.get(foot, "0.3"), label=lbl)
            else:  # an overlay: the first session broad underneath, the others dashed on top
                mk = "o" if foot.endswith("left") else "s"
                ax_d.plot(f, duty, marker=mk, ms=3, **session_style(si), label=lbl)
    ax_d.set(
        xlabel="drive frequency (Hz)",
        ylabel="duty factor (share on the ground)",
        ylim=(-0.03, 1.03),
        title="Time on the ground per step",
    )
    if len(analyses) > 1:
        fig.suptitle(f"Foot timing (top): {a0.label}")
    legend_below(fig, np.array(fig.axes), ncol=4)
    return fig


def _feet(a: SessionAnalysis) -> list[str]:
    if a.frame is None:
        return []
    have = {m for r in a.steps for m in r.markers}
    return [m for m in FOOT_COLORS if m in have]


def _height(a: SessionAnalysis, r: StepResult, foot: str) -> np.ndarray:
    assert a.frame is not None
    return r.markers[foot] @ a.frame.up * 1e3


def _grounds(a: SessionAnalysis, feet: list[str]) -> dict[str, float]:
    return {m: ground_level([_height(a, r, m) for r in a.steps if m in r.markers]) for m in feet}


def _chosen_steps(a: SessionAnalysis) -> list[StepResult]:
    steps = [r for r in a.steps if len(r.t_mocap) > 10 and r.markers]
    out = [r for hz in SHOW_HZ for r in steps[:] if r.frequency_hz == hz][: len(SHOW_HZ)]
    speeds = [(abs(float(r.row.get("body_speed_mm_s", np.nan))), r) for r in steps if r not in out]
    speeds = [(s, r) for s, r in speeds if np.isfinite(s)]
    if speeds:
        out.append(max(speeds, key=lambda x: x[0])[1])
    if not out and steps:
        out = [steps[len(steps) // 2]]
    return sorted(out, key=lambda r: r.frequency_hz)


def _timing(ax: Any, ax_s: Any, a: SessionAnalysis, r: StepResult, feet: list[str], ground: dict[str, float]) -> None:
    """Foot heights over the last cycles of a step on ``ax`` (mm) and, on the strip ``ax_s`` under it, a stance
    bar per foot (a row per foot, no height scale: a bar is a time span, not a height)."""
    f = step_frequency(r)
    t = r.t_mocap
    sel = t >= t[-1] - CYCLES / f
    cyc = (t[sel] - t[sel][0]) * f
    for k, foot in enumerate(feet):
        h = _height(a, r, foot) - ground[foot]
        st: Stance = foot_stance(t, h, 0.0)
        color = FOOT_COLORS.get(foot, "0.3")
        ax.plot(cyc, h[sel], ".-", ms=3, color=color, lw=1.0, label=f"{marker_name(foot)}: height (mocap samples)")
        dt = float(np.median(np.diff(cyc))) if len(cyc) > 1 else 0.0
        spans = _spans(cyc, st.mask[sel], dt)  # each sample on the ground stands for its own frame interval
        ax_s.broken_barh(spans, (k - 0.35, 0.7), color=color, label=f"{marker_name(foot)}: on the ground")
    ax.axhline(STANCE_MM, color="0.5", ls=":", lw=0.8, label=f"stance threshold ({STANCE_MM:g} mm)")
    speed = float(r.row.get("body_speed_mm_s", np.nan))
    why = " (paper)" if r.frequency_hz in SHOW_HZ else " (fastest)"
    title = f"{r.frequency_hz:g} Hz{why}: body {speed:+.0f} mm/s"
    ax.set(ylabel="height above ground (mm)", title=title)
    ax.xaxis.set_tick_params(labelbottom=False)
    ax_s.set(xlabel="drive cycles", ylim=(len(feet) - 0.5, -0.5), xlim=(0, CYCLES))
    ax_s.set_yticks(range(len(feet)), [marker_name(f) for f in feet])
    ax_s.grid(False, axis="y")
    ax_s.set_title("on the ground", fontsize=9, loc="left", pad=2)


def _spans(x: np.ndarray, mask: np.ndarray, dx: float) -> list[tuple[float, float]]:
    """(start, width) of each run of True in ``mask``, every sample widened to ±dx/2."""
    out: list[tuple[float, float]] = []
    for i in np.flatnonzero(mask):
        a = float(x[i]) - dx / 2
        if out and abs(out[-1][0] + out[-1][1] - a) < 1e-9:
            out[-1] = (out[-1][0], out[-1][1] + dx)
        else:
            out.append((a, dx))
    return out


def _duty(a: SessionAnalysis, foot: str, ground: float) -> tuple[np.ndarray, np.ndarray]:
    rows = sorted(
        (r.frequency_hz, foot_stance(r.t_mocap, _height(a, r, foot), ground).duty_factor)
        for r in a.steps
        if foot in r.markers and len(r.t_mocap) > 10
    )
    f, d = zip(*rows) if rows else ((), ())
    return np.array(f), np.array(d)
