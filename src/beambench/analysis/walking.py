"""The walker from its markers: body speed (paper Fig. 5, signed, mm/s along the walking axis) and each foot's
stance (ground contact from the foot's height), the gait timing the mocap shows."""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from beambench.analysis.trajectory import axis_vector


@dataclass(frozen=True)
class Speed:
    """Mean speed (mm/s, signed along ``forward``), its standard error and the distance covered (mm)."""

    speed_mm_s: float
    stderr_mm_s: float
    distance_mm: float
    n: int


NAN_SPEED = Speed(float("nan"), float("nan"), float("nan"), 0)


def body_speed(t_s: np.ndarray, body_xyz: np.ndarray, forward: str | np.ndarray = "x") -> Speed:
    """Least-squares slope of the body's position along ``forward`` against time.

    The slope averages out the body's oscillation at the drive frequency and tolerates missing frames.
    The standard error assumes independent residuals, so it is optimistic for oscillating residuals.
    """
    t = np.asarray(t_s, float)
    p = np.asarray(body_xyz, float)
    x = p @ axis_vector(forward) * 1e3
    ok = np.isfinite(t) & np.isfinite(x)
    t, x = t[ok], x[ok]
    if len(t) < 3 or np.ptp(t) <= 0:
        return NAN_SPEED
    tc = t - t.mean()
    slope = float(tc @ (x - x.mean()) / (tc @ tc))
    resid = x - x.mean() - slope * tc
    se = float(np.sqrt(resid @ resid / max(len(t) - 2, 1) / (tc @ tc)))
    return Speed(slope, se, slope * float(np.ptp(t)), len(t))


STANCE_MM = 0.4  # a foot within this of the ground is in stance: 4σ of the mocap's 0.1 mm noise


@dataclass(frozen=True)
class Stance:
    """A foot's ground contact from its mocap height: ``mask`` per sample (True = on the ground), the duty
    factor (share of the window's valid samples in stance) and the touchdown times (s, on the samples' clock)."""

    mask: np.ndarray
    duty_factor: float
    touchdown_s: np.ndarray


def ground_level(heights_mm: list[np.ndarray]) -> float:
    """The ground's height under a foot (mm): the median over the steps of each step's 5th-percentile height
    (the foot rests on the ground for part of most steps; a step where it never lands does not move this)."""
    lows = [float(np.nanpercentile(h, 5)) for h in heights_mm if np.isfinite(h).sum() >= 10]
    return float(np.median(lows)) if lows else float("nan")


def foot_stance(t_s: np.ndarray, height_mm: np.ndarray, ground_mm: float, within_mm: float = STANCE_MM) -> Stance:
    """Stance where the foot's height is within ``within_mm`` of the ground (per sample: at a few samples per
    drive cycle, smoothing would lift the brief stance of a fast gait off the ground)."""
    h = np.asarray(height_mm, float)
    ok = np.isfinite(h)
    mask = ok & (h <= ground_mm + within_mm)
    duty = float(mask.sum() / ok.sum()) if ok.any() else float("nan")
    starts = np.flatnonzero(mask[1:] & ~mask[:-1]) + 1
    return Stance(mask, duty, np.asarray(t_s, float)[starts])


SPEED_DEADBAND_MM_S = 5.0  # speeds closer to 0 have no direction: a stand-still's jitter is not a reversal


@dataclass(frozen=True)
class SpeedCurveShape:
    """Landmarks of a speed-vs-frequency curve (Hz, None where the curve has none): ``reverses_at_hz`` the lowest
    frequency where the walker turns from backward to forward, ``peak_at_hz`` where it walks forward fastest."""

    reverses_at_hz: float | None
    peak_at_hz: float | None


def speed_curve_shape(
    frequency_hz: np.ndarray, speed_mm_s: np.ndarray, deadband_mm_s: float = SPEED_DEADBAND_MM_S
) -> SpeedCurveShape:
    """Where a walker's speed curve changes sign and where it peaks.

    Parameters
    ----------
    frequency_hz, speed_mm_s
        The curve (any order; NaN speeds are dropped).
    deadband_mm_s
        Speeds within ± this have no direction. The reversal is the zero crossing, by linear interpolation,
        between the first backward point (≤ −deadband) followed by a forward one (≥ +deadband) with only
        dead-band points between them. The peak is the fastest forward point (≥ +deadband) refined by the
        parabola through it and its two neighbours (kept between them).
    """
    f = np.asarray(frequency_hz, float)
    v = np.asarray(speed_mm_s, float)
    keep = np.isfinite(f) & np.isfinite(v)
    order = np.argsort(f[keep])
    f, v = f[keep][order], v[keep][order]
    signed = [(fi, vi) for fi, vi in zip(f, v) if abs(vi) >= deadband_mm_s]
    reverses = None
    for (f0, v0), (f1, v1) in pairwise(signed):
        if v0 < 0 < v1:
            reverses = float(f0 + (f1 - f0) * (-v0) / (v1 - v0))
            break
    peak = None
    if len(v) and np.nanmax(v) >= deadband_mm_s:
        i = int(np.argmax(v))
        peak = float(f[i])
        if 0 < i < len(v) - 1:
            x, y = f[i - 1 : i + 2], v[i - 1 : i + 2]
            a, b, _ = np.polyfit(x, y, 2)
            if a < 0:
                peak = float(np.clip(-b / (2 * a), x[0], x[-1]))
    return SpeedCurveShape(reverses, peak)
