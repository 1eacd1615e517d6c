"""Speed tracking (``track:`` sessions): per-segment mean speed, RMS error, settling and direction times.

The speed judged here is the analysis' own, not the controller's: the least-squares slope of the body marker
along the forward axis over a centred :data:`WINDOW_S` window (several drive periods at walking frequencies),
every :data:`GRID_S`. Per segment (a ``/steps`` row; its target from the session's ``track`` stream):

- ``mean_speed_mm_s``: the slope over the record window (after ``track.settle_s``), as ``body_speed_mm_s``;
- ``speed_error_rms_mm_s``: RMS of windowed speed − target over the record window;
- ``tolerance_mm_s``: the goal, 15 % of |target|, at least 10 mm/s below 60 mm/s (and for a stop);
- ``settling_s``: from the segment's start until the windowed speed stays within the tolerance to its end;
- ``direction_s``: from the start until the windowed speed keeps the target's sign to the end (0 targets: NaN);
- ``max_frequency_hz``: the highest commanded frequency.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from beambench.analysis.trajectory import axis_vector
from beambench.analysis.walking import body_speed

WINDOW_S = 0.3
GRID_S = 0.02
REL_TOL, ABS_TOL_MM_S, ABS_BELOW_MM_S = 0.15, 10.0, 60.0
NS = 1e9


def tolerance(target_mm_s: float) -> float:
    """The goal's speed tolerance for a target (mm/s)."""
    return ABS_TOL_MM_S if abs(target_mm_s) < ABS_BELOW_MM_S else REL_TOL * abs(target_mm_s)


@dataclass
class TrackResult:
    """Times in s from the first segment's start. ``t``/``target``/… the controller's stream; ``speed_t``/
    ``speed`` the analysis' windowed body speed; ``segments`` one dict per segment (the table's columns)."""

    t: np.ndarray
    target: np.ndarray
    measured: np.ndarray
    frequency: np.ndarray
    feedforward: np.ndarray
    mode: np.ndarray
    speed_t: np.ndarray
    speed: np.ndarray
    bounds: list[tuple[float, float, float]] = field(default_factory=list)  # (start, settled, end) per segment
    segments: list[dict[str, Any]] = field(default_factory=list)


def windowed_speed(t_s: np.ndarray, x_mm: np.ndarray, grid: np.ndarray, window_s: float = WINDOW_S) -> np.ndarray:
    """Least-squares slope of ``x_mm`` over ``[g − w/2, g + w/2]`` at each grid time (NaN with < 10 samples)."""
    ok = np.isfinite(t_s) & np.isfinite(x_mm)
    t, x = t_s[ok], x_mm[ok]
    if len(t) < 10:
        return np.full(len(grid), np.nan)
    t0 = t[0]
    tt = t - t0
    c = [np.concatenate([[0.0], np.cumsum(a)]) for a in (np.ones_like(tt), tt, x, tt * tt, tt * x)]
    lo = np.searchsorted(t, grid - window_s / 2)
    hi = np.searchsorted(t, grid + window_s / 2)
    n, st, sx, stt, stx = (a[hi] - a[lo] for a in c)
    den = n * stt - st * st
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = (n * stx - st * sx) / den
    return np.where((n >= 10) & (den > 0), slope, np.nan)


def _stays(ok: np.ndarray, t: np.ndarray, start: float) -> float:
    """Time from ``start`` after which ``ok`` holds to the end (NaN if it does not hold at the end)."""
    if not len(ok) or not ok[-1]:
        return float("nan")
    bad = np.flatnonzero(~ok)
    first = t[bad[-1] + 1] if len(bad) else t[0]
    return float(first - start)


def track_result(
    track: Any, steps: Any, mocap_t_ns: np.ndarray, body_xyz: np.ndarray | None, forward: str
) -> TrackResult | None:
    """The tracking results of a session (None without a ``track`` stream, steps or a body marker)."""
    if track is None or not len(track.host_time_ns) or body_xyz is None or len(steps) == 0:
        return None
    t0 = int(steps["t_start_ns"].min())
    col = track.columns
    tt = (np.asarray(track.host_time_ns, np.int64) - t0) / NS
    mt = (np.asarray(mocap_t_ns, np.int64) - t0) / NS
    x = body_xyz @ axis_vector(forward) * 1e3
    grid = np.arange(0.0, tt[-1] + 1e-9, GRID_S)
    speed = windowed_speed(mt, x, grid)
    out = TrackResult(
        tt,
        np.asarray(col["target_mm_s"], float),
        np.asarray(col["measured_mm_s"], float),
        np.asarray(col["frequency_hz"], float),
        np.asarray(col["feedforward_hz"], float),
        np.asarray(col["mode"], int),
        grid,
        speed,
    )
    for row in steps.itertuples(index=False):
        a, s, b = ((int(v) - t0) / NS for v in (row.t_start_ns, row.t_settled_ns, row.t_end_ns))
        if row.t_end_ns < 0 or row.t_settled_ns < 0:
            continue
        out.bounds.append((a, s, b))
        ks = (tt >= a) & (tt <= b)
        target = float(np.median(out.target[ks])) if ks.any() else float("nan")
        tol = tolerance(target)
        seg = (grid >= a) & (grid <= b)
        rec = (grid >= s) & (grid <= b) & np.isfinite(speed)
        ws = (mt >= s) & (mt <= b)
        err = speed[rec] - target
        v_seg, t_seg = speed[seg], grid[seg]
        fin = np.isfinite(v_seg)
        within = np.abs(v_seg[fin] - target) <= tol
        out.segments.append(
            {
                "step": int(row.index),
                "target_speed_mm_s": target,
                "mean_speed_mm_s": body_speed(mt[ws], body_xyz[ws], forward).speed_mm_s,
                "speed_error_rms_mm_s": float(np.sqrt(np.mean(err**2))) if len(err) else float("nan"),
                "tolerance_mm_s": tol,
                "settling_s": _stays(within, t_seg[fin], a),
                "direction_s": _stays(np.sign(v_seg[fin]) == np.sign(target), t_seg[fin], a)
                if target != 0
                else float("nan"),
                "max_frequency_hz": float(np.max(out.frequency[ks])) if ks.any() else float("nan"),
            }
        )
    return out
