"""Contact events, ratio and regime of a record window (Fig. 1b, 4) — from the plate's normal force alone.

The detection itself lives in :mod:`beambench.acquisition.forces.contact_events` (pure numpy, below both the
simulator and the analysis, so the twin's regime maps and ``beambench analyze`` classify identically);
this module adds what needs the foot's motion (the velocity at touchdown).
"""

from __future__ import annotations

import numpy as np

__all__ = ["touchdown_velocity"]


def touchdown_velocity(
    touchdown_s: np.ndarray, t_s: np.ndarray, tangential_velocity: np.ndarray, window_s: float
) -> np.ndarray:
    """Mean tangential velocity over ``window_s`` just before each touchdown (NaN where no samples)."""
    t = np.asarray(t_s, float)
    v = np.asarray(tangential_velocity, float)
    out = np.full(len(touchdown_s), np.nan)
    for i, td in enumerate(np.asarray(touchdown_s, float)):
        sel = (t >= td - window_s) & (t <= td) & np.isfinite(v)
        if sel.any():
            out[i] = float(np.mean(v[sel]))
        else:
            j = int(np.clip(np.searchsorted(t, td), 0, len(t) - 1)) if len(t) else -1
            if j >= 0 and np.isfinite(v[j]) and abs(t[j] - td) <= 2 * window_s:
                out[i] = float(v[j])
    return out
