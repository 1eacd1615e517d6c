"""Walker body speed from the body marker (paper Fig. 5): signed, mm/s, along the walking axis."""

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
