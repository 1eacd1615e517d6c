"""Per-period path shape: self-crossings and loop sense of the phase-averaged path, and where it inverts.

A first-harmonic ellipse cannot see a figure-8 or an inversion. Here each tracked path (tip, foot; the walker's
feet) is averaged over the regime's period (k drive cycles in a 1/k regime, else one; see
:func:`~beambench.analysis.trajectory.mean_path`), and the closed mean loop gives:

- (a path whose scatter about its one-cycle mean is within 1.5× that about its k-cycle mean repeats every
  cycle: it is averaged over one, since k laps of one loop would cross themselves everywhere)
- the noise floor: the mocap noise of the session's paths (:func:`path_noise`: the 5th percentile over steps of
  the samples' scatter about their phase means, i.e. the steadiest steps) shrunk by the samples each mean-path
  point averages; a lobe thinner than ``NOISE_SIGMAS`` of it (mean thickness 2·area/perimeter) is noise, as is
  a whole loop that thin (a flat path);
- ``<marker>_crossings``: how often the loop crosses itself (an ellipse 0, a figure-8 1), counting only
  crossings whose lobes on both sides hold ≥ 5 % of the loop's convex-hull area (noise leaves tiny kinks) and
  are thicker than the noise floor;
- ``<marker>_loop_sense``: ``cw``/``ccw`` from the sign of its enclosed (shoelace) area in the (drive, up)
  plane, ``mixed`` where lobes of both senses nearly cancel (|net area| < 20 % of the convex hull's: a
  figure-8), ``""`` where there is no loop (or the loop is within the noise floor);
- ``<marker>_path_inverts``: the sense differs from the previous frequency's (same direction, kind and repeat;
  both ``cw``/``ccw``), i.e. the path inverts between these neighbouring steps.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from beambench.analysis.trajectory import mean_path

MIXED_SHARE = 0.2  # |net area| below this share of the hull's: lobes of both senses (a figure-8)
REPEAT_GAIN = 1.5  # folding at k cycles must cut the scatter by this factor to count as a k-cycle path
MIN_LOBE = 0.05  # a crossing counts when the lobes on both its sides hold this share of the hull's area
NOISE_SIGMAS = 4.0  # a lobe (or a whole loop) thinner than this many σ of the mean path's noise is noise


def self_crossings(loop: np.ndarray, min_lobe: float = MIN_LOBE, floor: float = 0.0) -> int:
    """Crossings of a closed polyline (``loop[-1] == loop[0]``) with itself that cut off a lobe of at least
    ``min_lobe`` of the convex hull's area, and thicker than ``floor`` (mean thickness 2·area/perimeter, same
    unit as the loop), on both sides (touching segments, and the tiny kinks noise leaves in a mean path, don't
    count)."""
    p = np.asarray(loop, float)
    if len(p) < 5 or thickness(p) < floor:
        return 0
    hull = _hull_area(p)
    if not hull > 0:
        return 0
    a, b = p[:-1], p[1:]
    n = len(a)
    d = b - a

    def cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

    # segment i against segment j: each one's ends on opposite sides of the other
    s1 = cross(d[:, None], a[None] - a[:, None])
    s2 = cross(d[:, None], b[None] - a[:, None])
    s3 = cross(d[None], a[:, None] - a[None])
    s4 = cross(d[None], b[:, None] - a[None])
    hit = (s1 * s2 < 0) & (s3 * s4 < 0)
    i, j = np.triu_indices(n, k=2)
    keep = ~((i == 0) & (j == n - 1))  # the first and last segments share the closing point
    count = 0
    for ii, jj in zip(i[keep][hit[i[keep], j[keep]]], j[keep][hit[i[keep], j[keep]]]):
        x = _intersection(a[ii], d[ii], a[jj], d[jj])
        inner = np.vstack([x, p[ii + 1 : jj + 1], x])  # the lobe between the two crossing segments
        outer = np.vstack([x, p[jj + 1 :], p[1 : ii + 1], x])
        if (
            min(_gross_area(inner), _gross_area(outer)) >= min_lobe * hull
            and min(thickness(inner), thickness(outer)) >= floor
        ):
            count += 1
    return count


def thickness(loop: np.ndarray) -> float:
    """Mean thickness of a closed polyline: 2 × the area it encloses / its length (a thin ellipse: ~0.8 × its
    minor axis; a back-and-forth line: 0)."""
    p = np.asarray(loop, float)
    length = float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))
    return 2 * _gross_area(p) / length if length > 0 else 0.0


def path_noise(steps: list[tuple[dict[str, np.ndarray], np.ndarray, float]]) -> float:
    """The mocap noise σ (per axis, mm) of a session's paths: each (paths, t, frequency) step's per-axis scatter
    about its one-cycle phase means, the 5th percentile over steps and markers (a path that does not repeat
    scatters more than the noise; the steadiest steps scatter by the noise alone). 0 when nothing can tell."""
    scatter = [_fold_rms(t, xy, 1 / f) / np.sqrt(2) for paths, t, f in steps if f > 0 for xy in paths.values()]
    scatter = [s for s in scatter if np.isfinite(s)]
    return float(np.percentile(scatter, 5)) if scatter else 0.0


def mean_path_noise(noise: float, samples: int, points: int) -> float:
    """σ of a mean-path point: the noise over √ of the samples it averages (``samples`` over ``points`` bins,
    and by :func:`~beambench.analysis.trajectory.mean_path`'s [1, 2, 1] smoothing, half of each neighbour's)."""
    if not (points > 0 and samples > 0):
        return 0.0
    return float(noise * np.sqrt(6 / 16 / (samples / points)))


def _intersection(a1: np.ndarray, d1: np.ndarray, a2: np.ndarray, d2: np.ndarray) -> np.ndarray:
    den = d1[0] * d2[1] - d1[1] * d2[0]
    u = ((a2[0] - a1[0]) * d2[1] - (a2[1] - a1[1]) * d2[0]) / den
    return a1 + u * d1


def _gross_area(loop: np.ndarray) -> float:
    """Area a closed polyline encloses, lobes of either sense adding (its hull's, for a kink-free one)."""
    return max(abs(signed_area(loop)), 0.0) if len(loop) < 4 else _hull_area(loop)


def _hull_area(points: np.ndarray) -> float:
    from scipy.spatial import ConvexHull, QhullError

    try:
        return float(ConvexHull(np.asarray(points, float)).volume)
    except (QhullError, ValueError):
        return 0.0


def signed_area(loop: np.ndarray) -> float:
    """Shoelace area of a closed polyline: > 0 counter-clockwise (x right, y up)."""
    x, y = np.asarray(loop, float).T
    return 0.5 * float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))


def loop_sense(loop: np.ndarray, floor: float = 0.0) -> str:
    """``cw``, ``ccw``, ``mixed`` (lobes of both senses nearly cancel) or ``""`` (no loop, or one thinner than
    ``floor``: a flat path whose enclosed area is noise)."""
    if len(loop) < 4 or thickness(loop) < floor:
        return ""
    hull = _hull_area(loop)
    net = signed_area(loop)
    if not hull > 0:
        return ""
    if abs(net) < MIXED_SHARE * hull:
        return "mixed"
    return "ccw" if net > 0 else "cw"


def period_cycles(regime: str) -> int:
    """k of a 1/k regime (the path repeats every k drive cycles), else 1."""
    if regime.startswith("1/"):
        try:
            return max(1, int(regime[2:]))
        except ValueError:
            return 1
    return 1


def shape_columns(
    paths: dict[str, np.ndarray], t_s: np.ndarray, frequency_hz: float, regime: str, noise: float = 0.0
) -> dict[str, Any]:
    """``<marker>_crossings`` and ``<marker>_loop_sense`` of each path over the regime's period, lobes and loops
    thinner than ``NOISE_SIGMAS`` of the mean path's share of the mocap ``noise`` (σ per axis, mm) not counted."""
    out: dict[str, Any] = {}
    if not frequency_hz > 0:
        return out
    k = period_cycles(regime)
    for name, xy in paths.items():
        # a path that repeats every cycle although the contacts repeat every k: one cycle (k laps of the same
        # loop would cross themselves everywhere)
        kk = (
            k
            if k > 1 and _fold_rms(t_s, xy, 1 / frequency_hz) > REPEAT_GAIN * _fold_rms(t_s, xy, k / frequency_hz)
            else 1
        )
        loop = mean_path(t_s, xy, kk / frequency_hz)
        n = int(np.sum(np.isfinite(t_s) & np.all(np.isfinite(xy), axis=1)))
        floor = NOISE_SIGMAS * mean_path_noise(noise, n, len(loop) - 1)
        out[f"{name}_crossings"] = self_crossings(loop, floor=floor) if len(loop) else np.nan
        out[f"{name}_loop_sense"] = loop_sense(loop, floor) if len(loop) else ""
    return out


def _fold_rms(t_s: np.ndarray, xy: np.ndarray, period_s: float, bins: int = 40) -> float:
    """RMS scatter of the samples about their phase-bin means when folded at ``period_s``."""
    ok = np.isfinite(t_s) & np.all(np.isfinite(xy), axis=1)
    t, p = np.asarray(t_s)[ok], np.asarray(xy)[ok]
    if len(t) < 2 * bins:
        return np.nan
    b = np.minimum((np.mod(t - t[0], period_s) / period_s * bins).astype(int), bins - 1)
    cnt = np.maximum(np.bincount(b, minlength=bins), 1)
    mean = np.column_stack([np.bincount(b, p[:, i], minlength=bins) / cnt for i in range(2)])
    return float(np.sqrt(np.mean(np.sum((p - mean[b]) ** 2, axis=1))))


def annotate_inversions(table: pd.DataFrame) -> pd.DataFrame:
    """``<marker>_path_inverts``: the loop sense flips from the previous frequency (same direction/kind/repeat)."""
    t = table.copy()
    senses = [c for c in t.columns if c.endswith("_loop_sense")]
    if not senses or "frequency_hz" not in t:
        return t
    keys = [c for c in ("direction", "kind", "repeat") if c in t]
    for c in senses:
        out = pd.Series(False, index=t.index)
        groups = t.groupby(keys) if keys else [(None, t)]
        for _, g in groups:
            g = g.sort_values("frequency_hz", kind="stable")
            s = g[c].astype(str)
            prev = s.shift(1)
            flip = s.isin(["cw", "ccw"]) & prev.isin(["cw", "ccw"]) & (s != prev)
            out.loc[g.index] = flip
        t[c.removesuffix("_loop_sense") + "_path_inverts"] = out
    return t
