"""Trajectory grid (paper Fig. 2f/g, 4a): one panel per commanded frequency, every panel at the same scale.

Contact rig: the foot relative to the stage, with the plate and the direction of motion at touchdown. Walker:
both feet relative to the body. Each step is drawn about its own mean position (the mean path's centre).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from beambench.acquisition.protocol.scenes import scene_or_unknown
from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import (
    FOOT_COLORS,
    PATH_CYCLES,
    R2_SENSE_MIN,
    REGIME_COLORS,
    UNCERTAIN,
    marker_name,
    new_figure,
    primary_marker,
    session_style,
    step_frequency,
)
from beambench.analysis.path_shape import NOISE_SIGMAS, mean_path_noise
from beambench.analysis.trajectory import mean_path
from beambench.common.figures import fitting_columns

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from beambench.analysis.session_analysis import SessionAnalysis, StepResult

NOISE_NOTE = (
    f"Crossings and senses are counted above a noise floor: a lobe (or a whole path) thinner than {NOISE_SIGMAS:g}σ "
    "of the mean path's noise does not count, σ being the mocap noise (measured as the scatter of the session's "
    "steadiest steps about their mean paths, steps.csv: path_noise_mm) over √ of the samples a mean-path point "
    "averages; a path that thin is 'flat'."
)
PLATE = "#8c564b"
TOUCHDOWN = "#ff7f0e"
BOX = 0.8  # panel height / width


STAGE_CAPTION = (
    "Paths relative to the stage in the (drive, up) plane, each step drawn about its own mean position: "
    "thin, the last cycles of the record window; bold, the mean path over the contact period with an arrow for "
    "its sense of travel (grey with '?' where the first-harmonic ellipse explains less than half of the path, "
    "R² < 0.5, so the sense is uncertain); brown, the plate (the foot's height at touchdown); orange, the foot's "
    "direction of motion along the plate at touchdown, drawn on the plate line. Each title: the mean path's loop "
    "sense (cw/ccw), or 'figure-8' / 'n crossings' where it crosses itself, and 'inverts' where its sense "
    "flipped from the previous frequency (steps.csv: foot_crossings, foot_loop_sense, foot_path_inverts). " + NOISE_NOTE
)
BODY_CAPTION = (
    "Both feet relative to the body in the (forward, up) plane, each step drawn about its own mean "
    "position: thin, the last cycles of the record window; bold, the mean path over one drive cycle with an "
    "arrow for its sense of travel (grey with '?' where the first-harmonic ellipse explains less than half of "
    "the path). The title says which steps are shown when there are more than fit; each panel's title the left "
    "foot's loop sense, 'figure-8' / 'n crossings' and 'inverts' as in steps.csv. " + NOISE_NOTE
)


@FIGURES.add(
    "trajectories",
    scenes=lambda s: s.driven,
    caption=lambda s: BODY_CAPTION if s.walks else STAGE_CAPTION,
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
    return fig_trajectories(analyses, path)


@dataclass
class _Marks:
    """What the panels collect for drawing once the common scale is known."""

    xh: float = 0.0
    yh: float = 0.0
    arrows: list[tuple[Any, float, float, float, str]] = field(default_factory=list)  # ax, x, y, sign, colour
    plates: list[tuple[Any, float, str]] = field(default_factory=list)  # ax, height, colour
    uncertain: bool = False
    noise_mm: float = 0.0  # the mocap noise σ per frame the bands are drawn from (0: no bands)

    def extend(self, x: float, y: float) -> None:
        self.xh, self.yh = max(self.xh, x), max(self.yh, y)


def shape_note(a: SessionAnalysis, r: StepResult, marker: str) -> str:
    """The panel title's path metrics (beambench.analysis.path_shape) of ``marker`` in step ``r``: its loop sense
    or "figure-8" (one self-crossing) / "n crossings", and "inverts" where the sense flipped from the previous
    frequency of the same branch."""
    t = a.table
    rows = t[t["step"] == r.index] if "step" in t else t.iloc[0:0]
    if rows.empty or f"{marker}_crossings" not in rows:
        return ""
    row = rows.iloc[0]
    n, sense = row.get(f"{marker}_crossings"), str(row.get(f"{marker}_loop_sense", "") or "")
    parts = []
    if pd.notna(n) and int(n) > 0:
        parts.append("figure-8" if int(n) == 1 else f"{int(n)} crossings")
    elif sense in ("cw", "ccw"):
        parts.append(sense)
    elif pd.notna(n) and sense == "":
        parts.append("flat")
    if bool(row.get(f"{marker}_path_inverts", False)):
        parts.append("inverts")
    return "".join(f" · {p}" for p in parts)


def _markers(a: SessionAnalysis, single: bool) -> list[str]:
    """The markers drawn for a session: both walker feet in a single-session report, else the primary one."""
    names = {m for r in a.steps for m in r.paths}
    if single and scene_or_unknown(a.rig).walks:
        feet = [m for m in FOOT_COLORS if m in names]
        if feet:
            return feet
    m = primary_marker(a)
    return [m] if m else []


def _choose(freqs: list[float], max_panels: int) -> tuple[list[float], str]:
    """Every step's frequency, or every k-th (k the smallest that fits) with a note saying which are shown."""
    if len(freqs) <= max_panels:
        return freqs, ""
    k = math.ceil(len(freqs) / max_panels)
    shown = freqs[::k]
    nth = {2: "2nd", 3: "3rd"}.get(k, f"{k}th")
    return (
        shown,
        f"{len(shown)} of {len(freqs)} steps shown: every {nth} ({shown[0]:g}, {shown[1]:g}, … {shown[-1]:g} Hz)",
    )


def fig_trajectories(analyses: list[SessionAnalysis], path: Path, max_panels: int = 48) -> Path | None:
    """The trajectory grid of one or more sessions; None if no session has a tracked path."""
    from matplotlib.ticker import MaxNLocator

    single = len(analyses) == 1
    markers = {id(a): _markers(a, single) for a in analyses}
    freqs = sorted({r.frequency_hz for a in analyses for r in a.steps if set(markers[id(a)]) & set(r.paths)})
    if not freqs:
        return None
    freqs, subset = _choose(freqs, max_panels)
    walker = all(scene_or_unknown(a.rig).walks for a in analyses)
    fig, axes, ncol, legend_cols, height = _grid(len(freqs))
    plate_up = {} if walker else _plate_heights(analyses)
    marks = _Marks()
    for k, f in enumerate(freqs):
        ax = axes[k // ncol][k % ncol]
        note = ""
        for si, a in enumerate(analyses):
            r = next((r for r in a.steps if r.frequency_hz == f and set(markers[id(a)]) & set(r.paths)), None)
            if r is not None:
                _draw_step(ax, r, markers[id(a)], None if single else si, plate_up.get(id(a)), marks, walker)
                if single and a.track is None:  # a track's frequency moves within a step: no steady noise estimate
                    _noise_bands(ax, r, markers[id(a)][0], marks)
                note = shape_note(a, r, markers[id(a)][0]) if single else ""
        ax.set_title(f"{f:g} Hz{note}", pad=2, y=1.0)  # a fixed y skips measuring tick labels (slow)
    exaggeration = _limits(marks)
    _draw_marks(marks)
    for k in range(len(freqs), len(axes) * ncol):
        axes[k // ncol][k % ncol].set_visible(False)
    axes[0][0].set_xlim(-marks.xh, marks.xh)
    axes[0][0].set_ylim(-marks.yh, marks.yh)
    axes[0][0].xaxis.set_major_locator(MaxNLocator(4, symmetric=True))  # shared by every panel
    axes[0][0].yaxis.set_major_locator(MaxNLocator(4, symmetric=True))
    for j in range(ncol):
        last = max(i for i in range(len(axes)) if i * ncol + j < len(freqs))
        axes[last][j].set_xlabel(f"{'forward' if walker else 'drive'} (mm)")
        axes[last][j].xaxis.set_tick_params(labelbottom=True)
    for row in axes:
        row[0].set_ylabel("up (mm)")
    names = sorted({m for ms in markers.values() for m in ms})
    title = (
        f"{' and '.join(marker_name(m) for m in names).capitalize()} paths"
        + (" (the beam's contact end, not the tip)" if names == ["foot"] else "")
        + f" relative to the {'body' if walker else 'stage'}; each step drawn about its own mean position, same scale"
    )
    if exaggeration >= 1.5:
        title += f" (vertical ×{exaggeration:.0f})"
    notes = [subset] if subset else []
    if plate_up and any(abs(y) > marks.yh for _, y, _ in marks.plates):
        notes.append("no contact in panels without a plate line: the plate is further below")
    handles = _handles(analyses, markers, marks, single)
    ncol = fitting_columns([str(h.get_label()) for h in handles], float(fig.get_figwidth()), legend_cols)
    height = _legend_room(fig, height, math.ceil(len(handles) / ncol))
    fig.suptitle("\n".join([title, *notes]), y=1 - 0.1 / height, va="top")
    fig.legend(handles=handles, loc="lower center", ncol=ncol, bbox_to_anchor=(0.5, 0.0))
    fig.savefig(path)
    return path


LEGEND_ROW, XLABELS = 0.22, 0.75  # in: one legend row; the x tick labels and label below the lowest panels


def _legend_room(fig: Figure, height: float, rows: int) -> float:
    """Make the figure taller where its legend's ``rows`` need more room below the panels than the grid left
    (the panels keep their size); returns the figure's height (in)."""
    sp = fig.subplotpars
    bottom, top = sp.bottom * height, (1 - sp.top) * height
    extra = XLABELS + LEGEND_ROW * rows - bottom
    if extra <= 0:
        return height
    new = height + extra
    fig.set_size_inches(float(fig.get_figwidth()), new)
    fig.subplots_adjust(bottom=(bottom + extra) / new, top=1 - top / new)
    return new


def _grid(n: int) -> tuple[Figure, Any, int, int, float]:
    """A fixed layout of ``n`` equal panels (a layout engine spends seconds measuring 40 panels' tick labels):
    the figure, the axes grid, its columns, the legend's columns and the figure's height (in)."""
    ncol = n if n <= 5 else min(8, math.ceil(math.sqrt(2 * n)))
    nrow = math.ceil(n / ncol)
    pw = 1.9  # panel width (in)
    left, right, top, gapx, gapy = 0.75, 0.2, 0.78, 0.18, 0.42
    width = max(left + right + ncol * pw + (ncol - 1) * gapx, 7.5)  # room for the legend below
    pw = (width - left - right - (ncol - 1) * gapx) / ncol
    ph = pw * BOX
    legend_cols = max(1, int(width // 3.6))
    bottom = XLABELS + LEGEND_ROW * math.ceil(6 / legend_cols)  # x labels, then six legend entries (more: grown)
    height = top + bottom + nrow * ph + (nrow - 1) * gapy
    fig = new_figure((width, height), layout=None)
    axes = fig.subplots(nrow, ncol, sharex=True, sharey=True, squeeze=False)
    fig.subplots_adjust(
        left=left / width,
        right=1 - right / width,
        top=1 - top / height,
        bottom=bottom / height,
        wspace=gapx / pw,
        hspace=gapy / ph,
    )
    return fig, axes, ncol, legend_cols, height


def _plate_heights(analyses: list[SessionAnalysis]) -> dict[int, float]:
    """The plate's height in the stage frame: the foot's median height at touchdown over the whole session."""
    out: dict[int, float] = {}
    for a in analyses:
        heights = [r.touchdown_xy[:, 1] for r in a.steps if len(r.touchdown_xy)]
        if heights:
            out[id(a)] = float(np.nanmedian(np.concatenate(heights)))
    return out


def _contact_period_cycles(r: StepResult) -> int:
    """k of a 1/k contact regime (the path repeats every k drive cycles), else 1."""
    reg = str(r.row.get("regime", ""))
    if reg.startswith("1/"):
        try:
            return max(1, int(reg[2:]))
        except ValueError:
            return 1
    return 1


def _last_cycles(t: np.ndarray, xy: np.ndarray, f: float, max_s: float = 1.0) -> np.ndarray:
    if len(t) == 0 or not (f and np.isfinite(f) and f > 0):
        return xy
    return xy[t >= t[-1] - min(PATH_CYCLES / f, max_s)]


def _draw_step(
    ax: Any, r: StepResult, markers: list[str], si: int | None, plate: float | None, marks: _Marks, walker: bool
) -> None:
    """One session's step in its panel: raw and mean paths of each marker (``si`` None: a single session)."""
    fa = step_frequency(r)
    centre = None
    for m in markers:
        if m not in r.paths:
            continue
        xy = _last_cycles(r.t_mocap, r.paths[m], fa)
        ok = np.all(np.isfinite(xy), axis=1)
        if ok.sum() < 3:
            continue
        mp = mean_path(r.t_mocap, r.paths[m], _contact_period_cycles(r) / fa)
        # the centre every line of this marker is drawn about: the mean path's (steady), else the raw path's
        c = np.nanmean(mp, axis=0) if len(mp) > 3 else np.nanmean(xy[ok], axis=0)
        if m == markers[0]:
            centre = c
        if si is None:
            color = FOOT_COLORS.get(m, "#1f77b4") if walker else "#1f77b4"
            style: dict[str, Any] = _foot_style(markers.index(m), color) if walker else dict(color=color, lw=1.8)
            ax.plot(xy[ok, 0] - c[0], xy[ok, 1] - c[1], lw=0.5, color=color, alpha=0.3)
            lo, hi = np.percentile(xy[ok] - c, [0.5, 99.5], axis=0)
            marks.extend(max(abs(lo[0]), abs(hi[0])), max(abs(lo[1]), abs(hi[1])))
        else:
            style = session_style(si)
        if len(mp) > 3:
            _mean_path(ax, mp - c, str(style["color"]), float(r.row.get(f"{m}_ellipse_r2", np.nan)), style, marks)
    if centre is None:
        return
    overlay: str | None = str(session_style(si)["color"]) if si is not None else None
    if plate is not None:
        marks.plates.append((ax, plate - float(centre[1]), overlay or PLATE))
    if len(r.touchdown_xy) and np.isfinite(r.touchdown_v).any():
        sgn = float(np.sign(np.nanmedian(r.touchdown_v)))
        x = float(np.nanmedian(r.touchdown_xy[:, 0])) - float(centre[0])
        y = plate - float(centre[1]) if plate is not None else float(np.nanmedian(r.touchdown_xy[:, 1]) - centre[1])
        if sgn:  # on the plate line: the touchdown is where the foot meets the plate
            marks.arrows.append((ax, x, y, sgn, overlay or TOUCHDOWN))
    regime = str(r.row.get("regime", ""))
    if si is None and regime and not walker:
        tag = REGIME_COLORS.get(regime, "0.3")
        ax.text(
            0.97,
            0.04,
            regime,
            transform=ax.transAxes,
            ha="right",
            va="bottom",
            fontsize=8,
            color=tag,
            fontweight="bold",
        )


NOISE_BAND, FLOOR_BAND = "0.9", "0.75"
RAW_SIGMAS = 2.0  # the raw traces' band: ±2σ of the per-frame noise holds 95 % of a still marker's frames


def _noise_bands(ax: Any, r: StepResult, marker: str, marks: _Marks) -> None:
    """The two noise bands of :func:`noise_bands` behind a step's paths, about its centre."""
    if marker not in r.paths:
        return
    mp = mean_path(r.t_mocap, r.paths[marker], _contact_period_cycles(r) / step_frequency(r))
    raw, floor = noise_bands(r, marker, len(mp))
    if raw > 0:
        ax.axhspan(-raw, raw, color=NOISE_BAND, lw=0, zorder=0)
        ax.axhspan(-floor, floor, color=FLOOR_BAND, lw=0, zorder=0)
        marks.noise_mm = float(r.row.get("path_noise_mm", 0.0))


def noise_bands(r: StepResult, marker: str, mean_points: int) -> tuple[float, float]:
    """Half-heights (mm) of the two bands drawn about a step's centre: ±2σ of the per-frame mocap noise (steps.csv:
    ``path_noise_mm``), the spread of a raw trace that did not move; and the mean path's noise floor
    (``NOISE_SIGMAS`` σ of a mean-path point of ``mean_points`` points), within which a path is 'flat'. (0, 0)
    where the session's noise is unknown."""
    noise = float(r.row.get("path_noise_mm", np.nan))
    xy = r.paths.get(marker)
    if not (np.isfinite(noise) and noise > 0) or xy is None or mean_points < 2:
        return 0.0, 0.0
    n = int(np.sum(np.all(np.isfinite(xy), axis=1)))
    return RAW_SIGMAS * noise, NOISE_SIGMAS * mean_path_noise(noise, n, mean_points - 1)


def _foot_style(k: int, color: str) -> dict[str, Any]:
    """The walker's feet in one panel: the first broad and pale underneath, the second thin and dashed on top
    (mirrored legs trace nearly the same path, and one must not hide the other)."""
    if k == 0:
        return dict(color=color, lw=2.6, alpha=0.5, zorder=2)
    return dict(color=color, lw=1.2, ls=(0, (4, 2)), zorder=3)


def _mean_path(ax: Any, mp: np.ndarray, color: str, r2: float, style: dict[str, Any], marks: _Marks) -> None:
    """The phase-averaged path with an arrow for its sense of travel (grey with "?" when the sense is unsure)."""
    ax.plot(mp[:, 0], mp[:, 1], **style)
    marks.extend(float(np.max(np.abs(mp[:, 0]))), float(np.max(np.abs(mp[:, 1]))))
    sure = bool(np.isfinite(r2) and r2 >= R2_SENSE_MIN)
    marks.uncertain |= not sure
    j = int(np.argmax(mp[:, 1]))  # sense of travel at the top of the path
    j2 = min(j + 2, len(mp) - 1)
    if j2 <= j:
        return
    arrow = dict(arrowstyle="-|>", color=color if sure else UNCERTAIN, lw=1.4, mutation_scale=12)
    ax.annotate("", xy=mp[j2], xytext=mp[j], arrowprops=arrow, zorder=5)
    if not sure:
        ax.annotate(
            "?", xy=mp[j2], xytext=(4, 3), textcoords="offset points", color=UNCERTAIN, fontsize=10, fontweight="bold"
        )


def _limits(marks: _Marks) -> float:
    """Set the common half-ranges (a plate just below the path kept in view); returns the vertical exaggeration."""
    for _, y, _ in marks.plates:
        if abs(y) < 1.6 * max(marks.yh, 1e-9):
            marks.yh = max(marks.yh, abs(y))
    xh, yh = (marks.xh or 1.0) * 1.12, (marks.yh or 1.0) * 1.12
    exaggeration = BOX * xh / yh
    if exaggeration < 1.0:
        xh = yh / BOX
    elif exaggeration < 1.5:
        yh = BOX * xh
    marks.xh, marks.yh = xh, yh
    return max(1.0, BOX * xh / yh)


def _draw_marks(marks: _Marks) -> None:
    """Plate lines (where in view) and touchdown arrows, whose length is a share of the common scale."""
    for ax, y, color in marks.plates:
        if abs(y) <= marks.yh:
            ax.axhline(y, color=color, lw=1.6, alpha=0.6, zorder=1)
    for ax, x, y, sgn, color in marks.arrows:
        arrow = dict(arrowstyle="-|>", color=color, lw=1.8)
        ax.annotate("", xy=(x + sgn * 0.4 * marks.xh, y), xytext=(x, y), arrowprops=arrow, zorder=6)
        ax.plot([x], [y], "o", ms=3.5, color=color, zorder=6)


def _handles(analyses: list[SessionAnalysis], markers: dict[int, list[str]], marks: _Marks, single: bool) -> list[Any]:
    from matplotlib.lines import Line2D

    handles: list[Any] = []
    if single:
        walker = scene_or_unknown(analyses[0].rig).walks
        for k, m in enumerate(markers[id(analyses[0])]):
            color = FOOT_COLORS.get(m, "#1f77b4") if walker else "#1f77b4"
            mean = _foot_style(k, color) if walker else dict(color=color, lw=1.8)
            mean.pop("zorder", None)
            name = marker_name(m)
            handles.append(
                Line2D([], [], color=color, lw=0.6, alpha=0.5, label=f"{name}: raw, last {PATH_CYCLES} cycles (≤ 1 s)")
            )
            period = "one drive cycle" if walker else "the contact period"
            handles.append(Line2D([], [], **mean, label=f"{name}: mean path over {period} (arrow: sense)"))
        if marks.arrows:
            handles.append(
                Line2D(
                    [], [], color=TOUCHDOWN, marker="o", ms=3.5, lw=1.8, label="touchdown: direction along the plate"
                )
            )
        if marks.plates:
            handles.append(Line2D([], [], color=PLATE, lw=2.2, label="plate (foot height at touchdown)"))
        if marks.noise_mm > 0:
            from matplotlib.patches import Patch

            sigma = f"σ {marks.noise_mm:.2f} mm"
            handles.append(Patch(color=NOISE_BAND, label=f"±{RAW_SIGMAS:g}σ mocap noise per frame ({sigma})"))
            handles.append(Patch(color=FLOOR_BAND, label=f"mean path's noise floor (±{NOISE_SIGMAS:g}σ of its points)"))
    else:
        handles += [
            Line2D(
                [],
                [],
                **{**session_style(i), "zorder": None},
                label=f"{a.label} ({', '.join(marker_name(m) for m in markers[id(a)])})",
            )
            for i, a in enumerate(analyses)
        ]
        if marks.arrows:
            handles.append(Line2D([], [], color="0.4", marker="o", ms=3.5, lw=1.8, label="touchdown direction"))
        if marks.plates:
            handles.append(Line2D([], [], color="0.4", lw=2.2, alpha=0.8, label="plate (foot height at touchdown)"))
    if marks.uncertain:
        handles.append(
            Line2D(
                [],
                [],
                color=UNCERTAIN,
                marker="$?$",
                ms=7,
                lw=1.4,
                label=f"sense uncertain (ellipse R² < {R2_SENSE_MIN:g})",
            )
        )
    return handles
