"""First-harmonic ellipse of the tip (walker: foot) path against frequency: axis lengths, tilt and sense of travel
(paper Fig. 2e). The tilt of an axis is defined modulo 180°; it is unwrapped along the sweep so a path turning
through vertical reads as one curve, not a jump from +90° to −90°."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from beambench.acquisition.protocol.scenes import scene_or_unknown
from beambench.analysis.figures.registry import FIGURES, ReportOptions
from beambench.analysis.figures.style import (
    R2_SENSE_MIN,
    SESSION_COLORS,
    UNCERTAIN,
    by_frequency,
    marker_name,
    new_figure,
    primary_marker,
    wrapped,
)
from beambench.common.figures import legend_below

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from beambench.analysis.session_analysis import SessionAnalysis

SENSE_NAMES = {"ccw": "counter-clockwise", "cw": "clockwise", "": "line (no sense)"}


@FIGURES.add(
    "ellipse",
    scenes=lambda s: s.driven,
    caption="First-harmonic ellipse of the tip path (walker: the left foot relative to the body): full axis "
    "lengths, tilt of the major axis (unwrapped along the sweep from its lowest well-fitted frequency: an "
    "axis turning through vertical continues past ±90° instead of jumping by 180°) and sense of travel (paper Fig. 2e). The walker's foot path is relative to the "
    "body: where the body rocks on its slider while the feet stay put, the major axis is the body's swing.",
)
def draw(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
    fig = ellipse_figure(analyses)
    if fig is None:
        return None
    fig.savefig(path)
    return path


def ellipse_marker(a: SessionAnalysis) -> str:
    """The point whose ellipse is drawn: the tip on the contact rig, else the primary marker (a foot)."""
    return "tip" if "tip_major_mm" in a.table else (primary_marker(a) or "")


def point_title(a: SessionAnalysis, m: str) -> str:
    """The figure's title: which point's path (the tip here, while trajectories.png shows the foot)."""
    if m == "tip":
        return "Tip path (the beam's free end; the trajectory grid shows the foot, whose sense can differ)"
    relative = "the body" if scene_or_unknown(a.rig).walks else "the stage"
    return f"{marker_name(m).capitalize()} path relative to {relative}"


def ellipse_figure(analyses: list[SessionAnalysis]) -> Figure | None:
    """Axis lengths, tilt and sense of each session's tip (walker: foot) path; None if none has one."""
    fig = new_figure((12, 4.6))
    axes = fig.subplots(1, 2)
    anything = False
    titles: list[str] = []
    for si, a in enumerate(analyses):
        t = by_frequency(a)
        m = ellipse_marker(a)
        if f"{m}_major_mm" not in t:
            continue
        anything = True
        titles.append(point_title(a, m))
        c = SESSION_COLORS[si % 4]
        sfx = f" ({a.label})" if len(analyses) > 1 else ""
        f = t["frequency_hz"]
        lw = 2.4 if len(analyses) > 1 and si == 0 else 1.2
        alpha = 0.5 if len(analyses) > 1 and si == 0 else 1.0
        name = marker_name(m)
        axes[0].plot(f, t[f"{m}_major_mm"], "-", color=c, lw=lw, alpha=alpha, label=f"{name} major axis{sfx}")
        axes[0].plot(f, t[f"{m}_minor_mm"], "--", color=c, lw=lw, alpha=alpha, label=f"{name} minor axis{sfx}")
        sense = t[f"{m}_sense"].fillna("").astype(str)
        r2 = t.get(f"{m}_ellipse_r2", pd.Series(np.nan, index=t.index)).astype(float)
        sure = r2 >= R2_SENSE_MIN
        tilt = unwrapped_tilt(t[f"{m}_tilt_deg"], sure)
        size = 60 if len(analyses) > 1 and si == 0 else 28
        axes[1].plot(f, tilt, "-", color=c, lw=0.6, alpha=0.4)
        for s, style in (
            ("ccw", dict(marker="o", facecolors=c, edgecolors=c)),
            ("cw", dict(marker="o", facecolors="none", edgecolors=c)),
            ("", dict(marker="x", c=c)),
        ):
            sel = (sense == s) & (sure | (s == ""))
            if sel.any():
                axes[1].scatter(f[sel], tilt[sel], s=size, label=f"{SENSE_NAMES[s]}{sfx}", **style)
        unsure = (sense != "") & ~sure
        if unsure.any():
            label = f"sense uncertain (ellipse R² < {R2_SENSE_MIN:g}){sfx}"
            axes[1].scatter(f[unsure], tilt[unsure], s=size * 1.6, marker="$?$", c=UNCERTAIN, label=label)
        noise = float(t["path_noise_mm"].iloc[0]) if "path_noise_mm" in t and len(t) else float("nan")
        if len(analyses) == 1 and np.isfinite(noise) and noise > 0:
            axes[0].axhline(
                4 * noise,
                color=UNCERTAIN,
                ls=":",
                lw=1.2,
                label=f"mocap noise: ±2σ per frame ({4 * noise:.2f} mm wide)",
            )
        why = why_uncertain(t, m)
        if len(analyses) == 1 and why:  # below the points: the axis extended to hold it
            lo, hi = axes[1].get_ylim()
            axes[1].set_ylim(lo - 0.55 * (hi - lo), hi)
            axes[1].text(
                0.02,
                0.02,
                wrapped(why, 5.0, 8.5),
                transform=axes[1].transAxes,
                fontsize=8.5,
                va="bottom",
                ha="left",
                bbox=dict(boxstyle="round", fc="white", ec=UNCERTAIN, alpha=0.9),
                zorder=6,
            )
    if not anything:
        return None
    axes[0].set(xlabel="drive frequency (Hz)", ylabel="axis length (mm)", title="Axis lengths")
    axes[1].set(
        xlabel="drive frequency (Hz)",
        ylabel="tilt of major axis from drive axis (deg)",
        title="Tilt (unwrapped) and sense of travel",
    )
    axes[1].axhline(0, color="0.6", lw=0.8)
    fig.suptitle(" / ".join(dict.fromkeys(titles)) + ": first-harmonic ellipse")
    legend_below(fig, axes, ncol=4)
    return fig


def why_uncertain(t: pd.DataFrame, m: str) -> str:
    """Why no step's sense is certain, when none is (every ellipse R² below ``R2_SENSE_MIN``): the R² range and, where
    the session's mocap noise is known, the path's size against the noise's spread; "" when some step's is."""
    r2 = t.get(f"{m}_ellipse_r2", pd.Series(np.nan, index=t.index)).astype(float)
    fitted = r2[np.isfinite(r2)]
    if not len(fitted) or (fitted >= R2_SENSE_MIN).any():
        return ""
    text = (
        f"No step's tilt or sense is certain: the ellipse explains less than {R2_SENSE_MIN:.0%} of the path at every "
        f"step (R² {fitted.min():.2f}–{fitted.max():.2f})."
    )
    noise = float(t["path_noise_mm"].iloc[0]) if "path_noise_mm" in t else float("nan")
    major = t.get(f"{m}_major_mm", pd.Series(np.nan, index=t.index)).astype(float)
    if np.isfinite(noise) and noise > 0 and np.isfinite(major).any():
        text += (
            f" The {marker_name(m)} moves {np.nanmin(major):.2f}–{np.nanmax(major):.2f} mm (major axis) where the "
            f"mocap noise spreads a still marker over {4 * noise:.2f} mm (±2σ per frame, steps.csv: path_noise_mm): "
            "the noise is most of the path."
        )
    return text


def unwrapped_tilt(tilt_deg: pd.Series, sure: pd.Series | None = None) -> pd.Series:
    """The tilt of an axis (defined modulo 180°) unwrapped along the rows (frequency order), its first ``sure``
    row (else its first row) kept within ±90°; NaN rows stay NaN."""
    v = tilt_deg.astype(float).to_numpy().copy()
    ok = np.isfinite(v)
    if ok.sum() > 1:
        u = np.unwrap(v[ok], period=180.0)
        anchor = np.flatnonzero(sure.to_numpy()[ok]) if sure is not None else np.zeros(0, int)
        k = int(anchor[0]) if len(anchor) else 0
        v[ok] = u - 180.0 * np.round(u[k] / 180.0)
    return pd.Series(v, index=tilt_deg.index)
