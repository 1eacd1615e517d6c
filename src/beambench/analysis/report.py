"""The analysis report: PNG figures, a per-step CSV and an ``index.html`` with the session's provenance.

``make_report([analysis], out)`` for one session; with two or more analyses every figure overlays them
(``beambench compare``). Figures follow the paper: trajectory grid (Fig. 2f/g, 4a), contact frequency vs input
frequency (Fig. 1b), force traces (Fig. 4b), walking speed (Fig. 5), plus drive accuracy, ellipse axes,
direction at contact and clock-sync diagnostics.
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, cast

import numpy as np
import pandas as pd
import yaml

from beambench.analysis.contact import REGIME_ORDER
from beambench.analysis.session import SessionAnalysis, StepResult
from beambench.analysis.track_figure import KEY as TRACK_KEY
from beambench.analysis.track_figure import fig_tracking
from beambench.analysis.trajectory import mean_path

if TYPE_CHECKING:
    from matplotlib.figure import Figure

REGIME_COLORS = {
    "1": "#1f77b4",
    "1/2": "#ff7f0e",
    "1/3": "#2ca02c",
    "1/4": "#d62728",
    "1/5": "#9467bd",
    "1/6": "#8c564b",
    "2": "#e377c2",
    "3": "#bcbd22",
    "continuous": "#222222",
    "none": "#b0b0b0",
    "irregular": "#7f7f7f",
    "": "#b0b0b0",
}
REGIME_NAMES = {
    "1": "1 contact / cycle",
    "1/2": "1 contact / 2 cycles",
    "1/3": "1 contact / 3 cycles",
    "1/4": "1 contact / 4 cycles",
    "continuous": "continuous contact",
    "none": "no contact",
    "irregular": "irregular",
}
SESSION_COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd"]
SESSION_MARKERS = ["o", "s", "^", "D"]
PATH_CYCLES = 6
PAPER_WALKER = [(23.0, -35.7), (65.0, 156.3)]  # Sec. IV-B, mm/s


STYLE: dict[str, Any] = {
    "axes.grid": True,
    "grid.alpha": 0.3,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "font.size": 10,
    "axes.titlesize": 10,
    "legend.fontsize": 9,
    "legend.frameon": False,
}
R2_SENSE_MIN = 0.5  # below this share of the path explained by the first-harmonic ellipse, its sense is uncertain
UNCERTAIN = "0.55"  # colour of an uncertain sense


def _styled(fn: Callable[..., Path | None]) -> Callable[..., Path | None]:
    """Build the figure under the report's style without touching the global rcParams or pyplot's backend."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Path | None:
        import matplotlib

        with matplotlib.rc_context(cast(Any, STYLE)):
            return fn(*args, **kwargs)

    return wrapper


def _figure(figsize: tuple[float, float], layout: Literal["constrained"] | None = "constrained") -> Figure:
    """A figure of its own (not pyplot's): constrained layout keeps titles and labels inside the canvas."""
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, dpi=110, layout=layout)


def _legend_below(fig: Figure, axes: Any, ncol: int = 4, handles: list[Any] | None = None) -> None:
    """One legend for the figure, outside every panel (a legend inside hides traces), duplicates merged."""
    if handles is None:
        seen: dict[str, Any] = {}
        for ax in np.ravel(axes):
            for h, label in zip(*ax.get_legend_handles_labels()):
                seen.setdefault(label, h)
        handles_, labels = list(seen.values()), list(seen)
    else:
        handles_, labels = handles, [h.get_label() for h in handles]
    if handles_:
        fig.legend(handles_, labels, loc="outside lower center", ncol=min(ncol, len(handles_)))


def _session_style(si: int) -> dict[str, Any]:
    """Line style of session ``si`` in an overlay: the first broad and translucent, later ones thin and dashed
    on top, so identical traces (equal seeds) still show both."""
    color = SESSION_COLORS[si % len(SESSION_COLORS)]
    if si == 0:
        return dict(color=color, lw=2.6, alpha=0.45, ls="-", zorder=2)
    return dict(color=color, lw=1.1, alpha=1.0, ls=(0, (4, 2)) if si == 1 else (0, (1, 1.5)), zorder=3 + si)


def no_contact_anywhere(a: SessionAnalysis) -> bool:
    """The session has load-cell data and the foot touched the plate in none of its steps."""
    t = a.table
    if "n_contacts" not in t or not len(t):
        return False
    return bool((t["n_contacts"].fillna(0) == 0).all())


def primary_marker(a: SessionAnalysis) -> str | None:
    """The marker whose path the trajectory grid shows: the foot on the contact rig, a foot on the walker."""
    names: set[str] = set()
    for r in a.steps:
        names.update(r.paths)
    for m in ("foot", "tip", "foot_left", "foot_right"):
        if m in names:
            return m
    return next(iter(sorted(names)), None)


def _last_cycles(
    t: np.ndarray, xy: np.ndarray, f: float, cycles: float = PATH_CYCLES, max_s: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    if len(t) == 0 or not (f and np.isfinite(f) and f > 0):
        return t, xy
    sel = t >= t[-1] - min(cycles / f, max_s)
    return t[sel], xy[sel]


def _table(a: SessionAnalysis) -> pd.DataFrame:
    """The per-step table in frequency order (a sweep may run down or repeat frequencies)."""
    t = a.table
    return t.sort_values("frequency_hz", kind="stable") if "frequency_hz" in t else t


def _freq(r: StepResult) -> float:
    f = r.row.get("analysis_frequency_hz", np.nan)
    return float(f) if np.isfinite(f) else r.frequency_hz


# ------------------------------------------------------------------------------------------------ figures


def _contact_period_cycles(r: StepResult) -> int:
    """k of a 1/k contact regime (the path repeats every k drive cycles), else 1."""
    reg = str(r.row.get("regime", ""))
    if reg.startswith("1/"):
        try:
            return max(1, int(reg[2:]))
        except ValueError:
            return 1
    return 1


@_styled
def fig_trajectories(analyses: list[SessionAnalysis], path: Path, max_panels: int = 48) -> Path | None:
    """A grid of paths in the stage frame, one panel per commanded frequency, all at the same scale.

    Each step is drawn about its own mean position (the mean path's centre). Thin: the raw path over the last
    cycles; bold: the phase-averaged path over the contact period (k cycles in a 1/k regime) with an arrow for
    its sense of travel, grey with a "?" where the first-harmonic ellipse explains less than half the path
    (R² < 0.5); brown: the plate, at the foot's height at touchdown; orange: the foot's direction of motion
    along the plate at touchdown.
    """
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    marker = {id(a): primary_marker(a) or "" for a in analyses}
    freqs = sorted({r.frequency_hz for a in analyses for r in a.steps if marker[id(a)] in r.paths})
    if not freqs:
        return None
    if len(freqs) > max_panels:
        freqs = [freqs[int(i)] for i in np.linspace(0, len(freqs) - 1, max_panels).round()]
    n = len(freqs)
    ncol = n if n <= 5 else min(8, math.ceil(math.sqrt(2 * n)))
    nrow = math.ceil(n / ncol)
    walker = all(a.rig == "walker" for a in analyses)
    ref, xname = ("body", "forward") if walker else ("stage", "drive")
    # the plate's height in the stage frame: the foot's median height at touchdown over the whole session
    plate_up: dict[int, float] = {}
    for a in analyses:
        heights = [r.touchdown_xy[:, 1] for r in a.steps if len(r.touchdown_xy)]
        if heights and not walker:
            plate_up[id(a)] = float(np.nanmedian(np.concatenate(heights)))
    box = 0.8
    pw, ph = 1.9, 1.9 * box  # panel size (in)
    left, right, top, gapx, gapy = 0.75, 0.2, 0.62, 0.18, 0.42
    width = max(left + right + ncol * pw + (ncol - 1) * gapx, 7.5)  # room for the legend below
    pw = (width - left - right - (ncol - 1) * gapx) / ncol
    ph = pw * box
    legend_cols = max(1, int(width // 3.6))
    bottom = 0.75 + 0.22 * math.ceil(6 / legend_cols)  # x labels, then up to six legend entries
    height = top + bottom + nrow * ph + (nrow - 1) * gapy
    # a fixed layout: a layout engine spends seconds measuring 40 panels' tick labels
    fig = _figure((width, height), layout=None)
    axes = fig.subplots(nrow, ncol, sharex=True, sharey=True, squeeze=False)
    fig.subplots_adjust(
        left=left / width,
        right=1 - right / width,
        top=1 - top / height,
        bottom=bottom / height,
        wspace=gapx / pw,
        hspace=gapy / ph,
    )
    single = len(analyses) == 1
    xh = yh = 0.0
    arrows: list[tuple[Any, float, float, float, str]] = []
    plates: list[tuple[Any, float, str]] = []
    uncertain_any = False
    for k, f in enumerate(freqs):
        ax = axes[k // ncol][k % ncol]
        for si, a in enumerate(analyses):
            m = marker[id(a)]
            r = next((r for r in a.steps if r.frequency_hz == f and m in r.paths), None)
            if r is None:
                continue
            fa = _freq(r)
            xy = _last_cycles(r.t_mocap, r.paths[m], fa)[1]
            ok = np.all(np.isfinite(xy), axis=1)
            if ok.sum() < 3:
                continue
            kk = _contact_period_cycles(r)
            mp = mean_path(r.t_mocap, r.paths[m], kk / fa)
            # the centre every line of this step is drawn about: the mean path's (steady), else the raw path's
            c = np.nanmean(mp, axis=0) if len(mp) > 3 else np.nanmean(xy[ok], axis=0)
            style: dict[str, Any] = dict(color="#1f77b4", lw=1.8) if single else _session_style(si)
            color = str(style["color"])
            if single:
                ax.plot(xy[ok, 0] - c[0], xy[ok, 1] - c[1], lw=0.5, color=color, alpha=0.3)
                lo, hi = np.percentile(xy[ok] - c, [0.5, 99.5], axis=0)
                xh, yh = max(xh, abs(lo[0]), abs(hi[0])), max(yh, abs(lo[1]), abs(hi[1]))
            if len(mp) > 3:
                mp = mp - c
                ax.plot(mp[:, 0], mp[:, 1], **style)
                xh, yh = max(xh, float(np.max(np.abs(mp[:, 0])))), max(yh, float(np.max(np.abs(mp[:, 1]))))
                r2 = float(r.row.get(f"{m}_ellipse_r2", np.nan))
                sure = bool(np.isfinite(r2) and r2 >= R2_SENSE_MIN)
                uncertain_any |= not sure
                j = int(np.argmax(mp[:, 1]))  # sense of travel at the top of the path
                j2 = min(j + 2, len(mp) - 1)
                if j2 > j:
                    ax.annotate(
                        "",
                        xy=mp[j2],
                        xytext=mp[j],
                        arrowprops=dict(
                            arrowstyle="-|>", color=color if sure else UNCERTAIN, lw=1.4, mutation_scale=12
                        ),
                        zorder=5,
                    )
                    if not sure:
                        ax.annotate(
                            "?",
                            xy=mp[j2],
                            xytext=(4, 3),
                            textcoords="offset points",
                            color=UNCERTAIN,
                            fontsize=10,
                            fontweight="bold",
                        )
            if id(a) in plate_up:
                plates.append((ax, plate_up[id(a)] - float(c[1]), "#8c564b" if single else color))
            if len(r.touchdown_xy) and np.isfinite(r.touchdown_v).any():
                td = np.nanmedian(r.touchdown_xy, axis=0) - c
                sgn = float(np.sign(np.nanmedian(r.touchdown_v)))
                if sgn:
                    arrows.append((ax, td[0], td[1], sgn, "#ff7f0e" if single else color))
            regime = str(r.row.get("regime", ""))
            if single and regime:
                ax.text(
                    0.97,
                    0.04,
                    regime,
                    transform=ax.transAxes,
                    ha="right",
                    va="bottom",
                    fontsize=8,
                    color=REGIME_COLORS.get(regime, "0.3"),
                    fontweight="bold",
                )
        ax.set_title(f"{f:g} Hz", pad=2, y=1.0)  # a fixed y skips measuring tick labels (slow)
    for _, y, _ in plates:  # keep a plate the foot touches in view (it sits just below the path)
        if abs(y) < 1.6 * max(yh, 1e-9):
            yh = max(yh, abs(y))
    xh, yh = (xh or 1.0) * 1.12, (yh or 1.0) * 1.12
    exaggeration = box * xh / yh
    if exaggeration < 1.0:
        xh = yh / box
    elif exaggeration < 1.5:
        yh = box * xh
    exaggeration = max(1.0, box * xh / yh)
    for ax, x, y, sgn, color in arrows:
        ax.annotate(
            "", xy=(x + sgn * 0.4 * xh, y), xytext=(x, y), arrowprops=dict(arrowstyle="-|>", color=color, lw=1.8)
        )
        ax.plot([x], [y], "o", ms=3.5, color=color)
    below = 0
    for ax, y, color in plates:
        if abs(y) <= yh:
            ax.axhline(y, color=color, lw=1.6, alpha=0.6, zorder=1)
        else:
            below += 1
    for k in range(len(freqs), nrow * ncol):
        axes[k // ncol][k % ncol].set_visible(False)
    axes[0][0].set_xlim(-xh, xh)
    axes[0][0].set_ylim(-yh, yh)
    axes[0][0].xaxis.set_major_locator(MaxNLocator(4, symmetric=True))  # shared by every panel
    axes[0][0].yaxis.set_major_locator(MaxNLocator(4, symmetric=True))
    for j in range(ncol):
        last = max(i for i in range(nrow) if i * ncol + j < len(freqs))
        axes[last][j].set_xlabel(f"{xname} (mm)")
        axes[last][j].xaxis.set_tick_params(labelbottom=True)
    for row in axes:
        row[0].set_ylabel("up (mm)")
    names = {marker[id(a)] for a in analyses}
    handles: list[Any] = []
    if single:
        handles.append(
            Line2D(
                [],
                [],
                color="#1f77b4",
                lw=0.6,
                alpha=0.5,
                label=f"{'/'.join(names)}: raw, last {PATH_CYCLES} cycles (≤ 1 s)",
            )
        )
        handles.append(
            Line2D([], [], color="#1f77b4", lw=1.8, label="mean path over the contact period (arrow: sense)")
        )
        if arrows:
            handles.append(
                Line2D(
                    [], [], color="#ff7f0e", marker="o", ms=3.5, lw=1.8, label="touchdown: direction along the plate"
                )
            )
        if plates:
            handles.append(Line2D([], [], color="#8c564b", lw=2.2, label="plate (foot height at touchdown)"))
    else:
        handles += [
            Line2D([], [], **{**_session_style(i), "zorder": None}, label=f"{a.label} ({marker[id(a)]})")
            for i, a in enumerate(analyses)
        ]
        if arrows:
            handles.append(Line2D([], [], color="0.4", marker="o", ms=3.5, lw=1.8, label="touchdown direction"))
        if plates:
            handles.append(Line2D([], [], color="0.4", lw=2.2, alpha=0.8, label="plate (foot height at touchdown)"))
    if uncertain_any:
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
    title = f"{'/'.join(sorted(names)).capitalize()} paths relative to the {ref}; each step drawn about its own mean position, same scale"
    if exaggeration >= 1.5:
        title += f" (vertical ×{exaggeration:.0f})"
    if below and plate_up:
        title += "\nno contact in panels without a plate line: the plate is further below"
    fig.suptitle(title, y=1 - 0.1 / height, va="top")
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), legend_cols), bbox_to_anchor=(0.5, 0.0))
    fig.savefig(path)
    return path


@_styled
def fig_contact_frequency(analyses: list[SessionAnalysis], path: Path) -> Path | None:
    """Contact frequency against input frequency, coloured by regime, with f, f/2, f/3 guides (Fig. 1b)."""
    tables = [(a, _table(a)) for a in analyses if "contact_frequency_hz" in a.table]
    if not tables:
        return None
    fig = _figure((7.5, 5.0))
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
            st = _session_style(si)
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
    ax.set_xlim(0, fmax * 1.12)
    ax.set_ylim(bottom=-0.02 * fmax)
    ax.set_title(
        "Contact frequency vs input frequency" + ("" if single else " — " + " vs ".join(a.label for a, _ in tables))
    )
    _legend_below(fig, ax)
    fig.savefig(path)
    return path


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


@_styled
def fig_forces(
    analyses: list[SessionAnalysis], path: Path, frequencies: list[float], cycles: float = 6.0
) -> Path | None:
    """Normal and tangential plate force over a few drive cycles at chosen frequencies (Fig. 4b)."""
    if not frequencies:
        return None
    ncol = len(frequencies)
    fig = _figure((4.2 * ncol + 0.6, 6.0))
    axes = fig.subplots(2, ncol, sharex="col", squeeze=False)
    regimes: dict[int, list[str]] = {}
    for j, f in enumerate(frequencies):
        for si, a in enumerate(analyses):
            r = next((r for r in a.steps if r.frequency_hz == f and r.contacts is not None), None)
            if r is None or len(r.t_force) == 0:
                continue
            fa = _freq(r)
            c = r.contacts
            t0 = r.t_force[0]
            if c is not None and c.n_touchdowns:
                t0 = max(r.t_force[0], float(c.touchdown_s[0]) - 0.5 / fa)
            sel = (r.t_force >= t0) & (r.t_force <= t0 + cycles / fa)
            tt = (r.t_force[sel] - t0) * 1e3
            style = dict(color=SESSION_COLORS[0], lw=0.9) if len(analyses) == 1 else _session_style(si)
            reg, ratio = r.row.get("regime", ""), r.row.get("contacts_per_cycle", np.nan)
            regimes.setdefault(j, []).append(f"{a.label}: {reg or 'none'} ({ratio:.2f}/cycle)")
            lbl = a.label if len(analyses) > 1 else None
            axes[0][j].plot(tt, r.force[sel, 0], label=lbl, **style)
            axes[1][j].plot(tt, r.force[sel, 1], label=lbl, **style)
            if len(analyses) == 1 and c is not None:
                for s, e in zip(c.start_s, c.end_s):
                    if e >= t0 and s <= t0 + cycles / fa:
                        for ax in (axes[0][j], axes[1][j]):
                            ax.axvspan((s - t0) * 1e3, (e - t0) * 1e3, color="#ff7f0e", alpha=0.12, lw=0)
                axes[0][j].axhline(c.on_n, color="0.5", ls=":", lw=0.8)
            period_ms = 1e3 / fa
            for ax in (axes[0][j], axes[1][j]):
                ax.grid(False, axis="x")
                for kk in range(int(cycles) + 1):
                    ax.axvline(kk * period_ms, color="0.85", lw=0.6, zorder=0)
            if len(analyses) == 1:
                axes[0][j].set_title(f"{f:g} Hz: {REGIME_NAMES.get(reg, reg)} ({ratio:.2f} per cycle)")
            else:
                axes[0][j].set_title(f"{f:g} Hz\n" + "\n".join(regimes.get(j, [])), fontsize=9)
        axes[1][j].set_xlabel("time (ms); grey lines = drive periods")
        axes[1][j].axhline(0, color="0.3", lw=0.6)
    axes[0][0].set_ylabel("normal force (N)")
    axes[1][0].set_ylabel("tangential force (N)")
    if len(analyses) > 1:
        _legend_below(fig, axes)
    else:
        from matplotlib.lines import Line2D
        from matplotlib.patches import Patch

        _legend_below(
            fig,
            axes,
            handles=[
                Patch(color="#ff7f0e", alpha=0.25, label="contact"),
                Line2D([], [], color="0.5", ls=":", label="contact threshold (normal force)"),
            ],
        )
    fig.suptitle("Plate forces (calibrated)")
    fig.savefig(path)
    return path


@_styled
def fig_frequency(analyses: list[SessionAnalysis], path: Path) -> Path | None:
    """Commanded vs measured drive frequency (stage marker and motor encoder) and the stage amplitude."""
    fig = _figure((14, 4.3))
    axes = fig.subplots(1, 3)
    anything = False
    for si, a in enumerate(analyses):
        t = _table(a)
        if "frequency_hz" not in t:
            continue
        c = SESSION_COLORS[si % 4]
        suffix = f" ({a.label})" if len(analyses) > 1 else ""
        f = t["frequency_hz"]
        if "measured_frequency_hz" in t and t["measured_frequency_hz"].notna().any():
            axes[0].plot(f, t["measured_frequency_hz"], "o", color=c, ms=5, label="stage marker" + suffix)
            axes[1].plot(f, t["measured_frequency_hz"] - f, "o-", color=c, ms=4, lw=0.8, label="stage marker" + suffix)
            anything = True
        if "motor_frequency_hz" in t and t["motor_frequency_hz"].notna().any():
            axes[0].plot(f, t["motor_frequency_hz"], "x", color=c, ms=6, label="motor encoder" + suffix)
            axes[1].plot(f, t["motor_frequency_hz"] - f, "x--", color=c, ms=5, lw=0.8, label="motor encoder" + suffix)
            anything = True
        if "stage_amplitude_mm" in t and t["stage_amplitude_mm"].notna().any():
            axes[2].plot(f, t["stage_amplitude_mm"], "o-", color=c, ms=4, lw=0.8, label="measured" + suffix)
            cmd = t.get("commanded_amplitude_mm")
            if cmd is not None and cmd.notna().any():
                axes[2].axhline(float(cmd.dropna().iloc[0]), color=c, ls="--", lw=1, label="commanded" + suffix)
    if not anything:
        return None
    lim = [0, max(float(a.table["frequency_hz"].max()) for a in analyses) * 1.05]
    axes[0].plot(lim, lim, color="0.6", lw=1, label="measured = commanded")
    axes[0].set(xlabel="commanded frequency (Hz)", ylabel="measured frequency (Hz)", title="Drive frequency")
    axes[1].axhline(0, color="0.6", lw=1)
    axes[1].set(xlabel="commanded frequency (Hz)", ylabel="measured − commanded (Hz)", title="Frequency error")
    axes[2].set(
        xlabel="commanded frequency (Hz)", ylabel="stage amplitude (mm)", title="Stage amplitude (A of x = A·sin 2πft)"
    )
    for ax in axes:
        if not ax.get_legend_handles_labels()[0]:  # e.g. the walker has no stage marker
            ax.text(0.5, 0.5, "no data in this session", transform=ax.transAxes, ha="center", color="0.5")
    _legend_below(fig, axes, ncol=6)
    fig.savefig(path)
    return path


@_styled
def fig_walking(analyses: list[SessionAnalysis], path: Path) -> Path | None:
    """Walker body speed (signed, mm/s) against drive frequency, with the paper's two reported points."""
    tabs = [
        (a, _table(a)) for a in analyses if "body_speed_mm_s" in a.table and a.table["body_speed_mm_s"].notna().any()
    ]
    if not tabs:
        return None
    fig = _figure((7.5, 4.6))
    ax = fig.subplots()
    for si, (a, t) in enumerate(tabs):
        err = t.get("body_speed_stderr_mm_s")
        ax.errorbar(
            t["frequency_hz"],
            t["body_speed_mm_s"],
            yerr=None if err is None else err,
            fmt=SESSION_MARKERS[si % 4] + "-",
            color=SESSION_COLORS[si % 4],
            ms=4,
            lw=1,
            capsize=2,
            label=a.label,
        )
    ax.axhline(0, color="0.3", lw=0.8)
    px, py = zip(*PAPER_WALKER)
    ax.plot(px, py, "*", ms=13, mfc="none", mec="k", label="paper (Sec. IV-B)")
    ax.set(xlabel="drive frequency (Hz)", ylabel="body speed (mm/s, + forward)", title="Walking speed vs frequency")
    _legend_below(fig, ax)
    fig.savefig(path)
    return path


@_styled
def fig_ellipse(analyses: list[SessionAnalysis], path: Path) -> Path | None:
    """Ellipse of the tip path (major, minor axes and tilt) against frequency; filled = counter-clockwise."""
    fig = _figure((12, 4.3))
    axes = fig.subplots(1, 2)
    anything = False
    for si, a in enumerate(analyses):
        t = _table(a)
        m = "tip" if "tip_major_mm" in t else (primary_marker(a) or "")
        if f"{m}_major_mm" not in t:
            continue
        anything = True
        c = SESSION_COLORS[si % 4]
        sfx = f" ({a.label})" if len(analyses) > 1 else ""
        f = t["frequency_hz"]
        lw = 2.4 if len(analyses) > 1 and si == 0 else 1.2
        alpha = 0.5 if len(analyses) > 1 and si == 0 else 1.0
        axes[0].plot(f, t[f"{m}_major_mm"], "-", color=c, lw=lw, alpha=alpha, label=f"{m} major axis{sfx}")
        axes[0].plot(f, t[f"{m}_minor_mm"], "--", color=c, lw=lw, alpha=alpha, label=f"{m} minor axis{sfx}")
        sense = t[f"{m}_sense"].astype(str)
        r2 = t.get(f"{m}_ellipse_r2", pd.Series(np.nan, index=t.index)).astype(float)
        sure = r2 >= R2_SENSE_MIN
        names = {"ccw": "counter-clockwise", "cw": "clockwise", "": "line (no sense)"}
        size = 60 if len(analyses) > 1 and si == 0 else 28
        for s, style in (
            ("ccw", dict(marker="o", facecolors=c, edgecolors=c)),
            ("cw", dict(marker="o", facecolors="none", edgecolors=c)),
            ("", dict(marker="x", c=c)),
        ):
            sel = (sense == s) & (sure | (s == ""))
            if sel.any():
                axes[1].scatter(f[sel], t[f"{m}_tilt_deg"][sel], s=size, label=f"{names[s]}{sfx}", **style)
        unsure = (sense != "") & ~sure
        if unsure.any():
            axes[1].scatter(
                f[unsure],
                t[f"{m}_tilt_deg"][unsure],
                s=size * 1.6,
                marker="$?$",
                c=UNCERTAIN,
                label=f"sense uncertain (ellipse R² < {R2_SENSE_MIN:g}){sfx}",
            )
    if not anything:
        return None
    axes[0].set(xlabel="drive frequency (Hz)", ylabel="axis length (mm)", title="First-harmonic ellipse: axes")
    axes[1].set(
        xlabel="drive frequency (Hz)",
        ylabel="tilt of major axis from drive axis (deg)",
        title="Tilt and sense of travel",
    )
    axes[1].axhline(0, color="0.6", lw=0.8)
    _legend_below(fig, axes, ncol=4)
    fig.savefig(path)
    return path


@_styled
def fig_contact_direction(analyses: list[SessionAnalysis], path: Path) -> Path | None:
    """Foot velocity along the plate at touchdown and the mean tangential force, against frequency (Fig. 4)."""
    tabs = [
        (a, _table(a))
        for a in analyses
        if "mean_tangential_n" in a.table and a.table["mean_tangential_n"].notna().any()
    ]
    if not tabs:
        return None
    fig = _figure((12, 4.3))
    axes = fig.subplots(1, 2, sharex=True)
    single = len(tabs) == 1
    for si, (a, t) in enumerate(tabs):
        f = t["frequency_hz"]
        colors = [REGIME_COLORS.get(str(r), "0.5") for r in t["regime"]] if single else SESSION_COLORS[si % 4]
        lbl = None if single else a.label
        if "touchdown_velocity_mm_s" in t:
            axes[0].plot(
                f,
                t["touchdown_velocity_mm_s"],
                "-",
                color="0.75" if single else SESSION_COLORS[si % 4],
                lw=0.8,
                zorder=1,
            )
            axes[0].scatter(
                f, t["touchdown_velocity_mm_s"], c=colors, s=30, zorder=2, marker=SESSION_MARKERS[si % 4], label=lbl
            )
        axes[1].plot(
            f, t["mean_tangential_n"], "-", color="0.75" if single else SESSION_COLORS[si % 4], lw=0.8, zorder=1
        )
        axes[1].scatter(f, t["mean_tangential_n"], c=colors, s=30, zorder=2, marker=SESSION_MARKERS[si % 4], label=lbl)
    for ax in axes:
        ax.axhline(0, color="0.3", lw=0.8)
        ax.set_xlabel("drive frequency (Hz)")
    axes[0].set(ylabel="foot velocity along drive axis (mm/s)", title="Direction of motion at touchdown (vs plate)")
    axes[1].set(ylabel="mean tangential force in contact (N)", title="Tangential force")
    if single:
        from matplotlib.lines import Line2D

        present = [r for r in REGIME_ORDER if r in set(tabs[0][1]["regime"])]
        _legend_below(
            fig,
            axes,
            ncol=6,
            handles=[
                Line2D([], [], ls="", marker="o", color=REGIME_COLORS[r], label=REGIME_NAMES.get(r, r)) for r in present
            ],
        )
    else:
        _legend_below(fig, axes)
    fig.savefig(path)
    return path


@_styled
def fig_sync(analyses: list[SessionAnalysis], path: Path, max_points: int = 2500) -> Path | None:
    """Receive delay over the fitted clock (µs) against session time, per stream: a flat floor = a good fit."""
    rows = [(a, n, r) for a in analyses for n, r in a.residuals_us.items() if len(r)]
    if not rows:
        return None
    names = sorted({n for _, n, _ in rows})
    fig = _figure((4.6 * len(names), 3.8))
    axes = fig.subplots(1, len(names), squeeze=False)
    for j, n in enumerate(names):
        ax = axes[0][j]
        for si, a in enumerate(analyses):
            r = a.residuals_us.get(n)
            ts = a.residual_t_s.get(n)
            if r is None or not len(r) or ts is None:
                continue
            idx = np.linspace(0, len(r) - 1, min(max_points, len(r))).astype(int)
            ax.plot(
                ts[idx],
                r[idx] / 1e3,
                ".",
                ms=1.5,
                color=SESSION_COLORS[si % 4],
                alpha=0.6,
                label=a.label if len(analyses) > 1 else None,
            )
            fit = a.fits.get(n)
            if fit is not None and si == 0:
                ax.set_title(f"{n}: drift {fit.drift_ppm:+.1f} ppm, median delay {fit.residual_median_us / 1e3:.2f} ms")
        ax.set(xlabel="session time (s)", ylabel="receive delay above fit (ms)")
    if len(analyses) > 1:
        fig.legend(loc="outside lower center", ncol=len(analyses), markerscale=6)
    fig.savefig(path)
    return path


# ---------------------------------------------------------------------------------------------- html/csv


def _prov_rows(a: SessionAnalysis) -> list[tuple[str, str]]:
    g = a.general
    versions = g.get("versions") if isinstance(g.get("versions"), dict) else {}
    rows = [
        ("session file", str(a.path) if a.path else ""),
        ("protocol", a.protocol_name),
        ("rig", a.rig),
        ("backend", a.backend),
        ("started (UTC)", str(g.get("started_utc", ""))),
        ("host", str(g.get("host", ""))),
        ("git SHA", str(g.get("git_sha", ""))),
        ("load-cell calibration", a.calibration_source or "default"),
        ("steps", str(len(a.steps))),
    ]
    if a.frame is not None:
        rows.append(
            (
                "stage frame (world)",
                f"drive {np.round(a.frame.drive, 3).tolist()}, up {np.round(a.frame.up, 3).tolist()}",
            )
        )
    if a.edge_check is not None:
        e = a.edge_check
        rows.append(
            (
                "load-cell sync edge − mocap frame",
                f"median {e.median_s * 1e3:.3f} ms (5–95 %: {e.p05_s * 1e3:.3f} … {e.p95_s * 1e3:.3f} ms, {e.n} edges)",
            )
        )
    if a.delay is not None:
        d = a.delay
        rows.append(
            (
                "encoder → stage marker delay",
                f"{d.delay_s * 1e3:.2f} ms (quality {d.quality:.2f})"
                if np.isfinite(d.delay_s)
                else "n/a (one frequency only)",
            )
        )
    if versions:
        rows.append(("versions", " · ".join(f"{k} {v}" for k, v in versions.items())))
    return rows


CAPTIONS = {
    "trajectories": "Paths relative to the stage in the (drive, up) plane, each step drawn about its own mean position: thin, the last cycles of the record window; bold, the mean path over the contact period with an arrow for its sense of travel (grey with '?' where the first-harmonic ellipse explains less than half of the path, R² < 0.5, so the sense is uncertain); brown, the plate (the foot's height at touchdown); orange, the foot's direction of motion along the plate at touchdown.",
    "contact_frequency": "Touchdowns per second against the drive frequency (paper Fig. 1b). Guides at f, f/2, f/3. Hollow points at 0: continuous contact or none.",
    "forces": "Calibrated normal and tangential plate force over a few drive cycles (paper Fig. 4b). Shaded: detected contacts.",
    "contact_direction": "Foot velocity along the plate just before touchdown and the mean tangential force while in contact (paper Fig. 4).",
    "walking_speed": "Walker body speed from the body marker (least-squares slope over the record window).",
    "ellipse": "First-harmonic ellipse of the tip path: full axis lengths, tilt and sense of travel (paper Fig. 2e).",
    "frequency": "Commanded against measured drive frequency (stage marker sine fit; motor encoder speed) and the stage amplitude.",
    "sync": "Clock sync: each sample's receive delay above the fitted device→host clock line (lower envelope).",
}


def _html_table(df: pd.DataFrame) -> str:
    return df.to_html(index=False, float_format=lambda v: f"{v:.4g}", na_rep="", border=0, classes="data")


# The per-step columns shown in the report (the CSV has them all), with their headers and units.
SUMMARY_COLUMNS = {
    "frequency_hz": "drive (Hz)",
    "measured_frequency_hz": "measured (Hz)",
    "stage_amplitude_mm": "stage amplitude (mm)",
    "regime": "contact regime",
    "contacts_per_cycle": "contacts per cycle",
    "contact_frequency_hz": "contact frequency (Hz)",
    "peak_normal_n": "peak normal force (N)",
    "mean_tangential_n": "mean tangential force (N)",
    "touchdown_velocity_mm_s": "foot speed at touchdown (mm/s)",
    "tip_major_mm": "tip ellipse major (mm)",
    "tip_minor_mm": "tip ellipse minor (mm)",
    "tip_sense": "tip sense",
    "tip_ellipse_r2": "tip ellipse R²",
    "body_speed_mm_s": "body speed (mm/s)",
}


def summary_table(table: pd.DataFrame) -> pd.DataFrame:
    """The readable subset of the per-step table: a dozen columns with units in the headers, sense marked
    uncertain where the ellipse fit is poor."""
    cols = [c for c in SUMMARY_COLUMNS if c in table]
    out = _sorted(table)[cols].copy()
    if "tip_sense" in out and "tip_ellipse_r2" in out:
        poor = ~(out["tip_ellipse_r2"].astype(float) >= R2_SENSE_MIN) & (out["tip_sense"].astype(str) != "")
        out.loc[poor, "tip_sense"] = out.loc[poor, "tip_sense"].astype(str) + " (uncertain)"
    return out.rename(columns=SUMMARY_COLUMNS)


def _sorted(t: pd.DataFrame) -> pd.DataFrame:
    return t.sort_values("frequency_hz", kind="stable") if "frequency_hz" in t else t


def _no_contact_notes(analyses: list[SessionAnalysis]) -> list[str]:
    """A note at the top for each session whose foot never touched the plate (contact figures are then empty)."""
    notes = []
    for a in analyses:
        if no_contact_anywhere(a):
            who = "" if len(analyses) == 1 else f" in {html.escape(a.label)}"
            notes.append(
                "<p class='note'><strong>No contact anywhere" + who + ":</strong> the foot never touched the plate "
                "in any step (the normal force stayed below the contact threshold), so there are no contact "
                "regimes, touchdowns or contact forces to show. Lower <code>sim.plate_gap_mm</code> or raise "
                "<code>amplitude_mm</code> to bring the foot onto the plate.</p>"
            )
    return notes


def write_html(analyses: list[SessionAnalysis], out: Path, figures: dict[str, Path], csv_name: str) -> Path:
    """``index.html`` with the figures, provenance, clock fits and the per-step table."""
    title = "beambench report — " + " vs ".join(html.escape(a.label) for a in analyses)
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>{title}</title>",
        "<style>body{font-family:system-ui,sans-serif;margin:2em;max-width:1500px}"
        "img{max-width:100%;border:1px solid #ddd}figure{margin:1.5em 0}figcaption{color:#444;font-size:0.9em}"
        "table{border-collapse:collapse;font-size:0.85em}td,th{padding:2px 8px;border-bottom:1px solid #eee;text-align:left}"
        "pre{background:#f6f6f6;padding:0.8em;overflow:auto}.cols{display:flex;gap:2em;flex-wrap:wrap}"
        ".note{background:#fff4e0;border-left:4px solid #ff7f0e;padding:0.6em 1em}</style></head><body>",
        f"<h1>{title}</h1>",
        *_no_contact_notes(analyses),
        f"<p>Per-step results: the main columns are at the end of this page; all of them are in "
        f"<a href='{csv_name}'>{csv_name}</a>. Record windows only (t_settled → t_end of each step), "
        "all streams on the host clock through the fitted device clocks.</p>",
        "<h2>Provenance</h2><div class='cols'>",
    ]
    for a in analyses:
        rows = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in _prov_rows(a))
        proto = html.escape(str(a.general.get("protocol", "")))
        ident = a.general.get("identity")
        ident_text = html.escape(
            yaml.safe_dump(ident, sort_keys=False) if isinstance(ident, dict) else str(ident or "")
        )
        parts.append(
            f"<div><h3>{html.escape(a.label)}</h3><table>{rows}</table>"
            f"<details><summary>protocol YAML</summary><pre>{proto}</pre></details>"
            f"<details><summary>devices and model (identity)</summary><pre>{ident_text}</pre></details></div>"
        )
    parts.append("</div><h2>Figures</h2>")
    for key, p in figures.items():
        parts.append(
            f"<figure><img src='{p.name}' alt='{key}'><figcaption>{html.escape(CAPTIONS.get(key, key))}</figcaption></figure>"
        )
    parts.append("<h2>Clock fits</h2>")
    for a in analyses:
        cols = [
            "stream",
            "method",
            "drift_ppm",
            "offset_s",
            "n",
            "n_used",
            "n_rejected",
            "residual_median_us",
            "residual_p95_us",
            "residual_max_us",
            "rtt_min_us",
            "bound_us",
        ]
        st = a.sync_table
        parts.append(f"<h3>{html.escape(a.label)}</h3>" + _html_table(st[[c for c in cols if c in st]]))
    parts.append(
        f"<h2>Per-step results</h2><p>The main columns; every column ({max(len(a.table.columns) for a in analyses)}) "
        f"is in <a href='{csv_name}'>{csv_name}</a>.</p>"
    )
    for a in analyses:
        parts.append(
            f"<h3>{html.escape(a.label)}</h3><div style='overflow-x:auto'>"
            + _html_table(summary_table(a.table))
            + "</div>"
        )
    parts.append("</body></html>")
    path = out / "index.html"
    path.write_text("\n".join(parts))
    return path


def make_report(
    analyses: list[SessionAnalysis],
    out: str | Path,
    force_at: list[float] | None = None,
    progress: Callable[[str], None] | None = None,
) -> Path:
    """Write figures, ``steps.csv`` and ``index.html`` into ``out``; returns the html path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if len(analyses) == 1:
        table = analyses[0].table
    else:
        table = pd.concat([a.table.assign(session=a.label) for a in analyses], ignore_index=True)
        table = table[["session", *[c for c in table.columns if c != "session"]]]
    csv_name = "steps.csv"
    table.to_csv(out / csv_name, index=False)
    jobs: list[tuple[str, Callable[[Path], Path | None]]] = [
        ("trajectories", lambda p: fig_trajectories(analyses, p)),
        ("contact_frequency", lambda p: fig_contact_frequency(analyses, p)),
        ("forces", lambda p: fig_forces(analyses, p, choose_force_frequencies(analyses, force_at))),
        ("contact_direction", lambda p: fig_contact_direction(analyses, p)),
        ("walking_speed", lambda p: fig_walking(analyses, p)),
        ("ellipse", lambda p: fig_ellipse(analyses, p)),
        ("frequency", lambda p: fig_frequency(analyses, p)),
        ("sync", lambda p: fig_sync(analyses, p)),
        (TRACK_KEY, lambda p: fig_tracking(analyses, p)),  # track: sessions only (analysis/track_figure.py)
    ]
    figures: dict[str, Path] = {}
    for key, job in jobs:
        if progress is not None:
            progress(key)
        p = job(out / f"{key}.png")
        if p is not None:
            figures[key] = p
    return write_html(analyses, out, figures, csv_name)
