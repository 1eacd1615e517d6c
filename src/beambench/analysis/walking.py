"""The walker from its markers: body speed (paper Fig. 5, signed, mm/s along the walking axis) and each foot's
stance (ground contact from the foot's height), the gait timing the mocap shows."""

from __future__ import annotations

from dataclasses import dataclass

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
