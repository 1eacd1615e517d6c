"""Intervals on the calibrated unknowns from the local Jacobian of the targets' landmarks, and the spread of the
twin's landmarks over the near-best points.

The landmarks are the rig's numeric targets (:mod:`.checks`: the contact rig's transitions, the walker's
speeds; not the signs). A weighted linear fit of each over the evaluated points around the winner
(:func:`~.landmark_steps.fit_local_linear`, unit coordinates of the free unknowns) gives the Jacobian ``J``;
reading each target's tolerance as 2σ, ``C = (Jᵀ W J)⁻¹`` (``W = diag(1/σ²)``) is the linearised covariance of
the unknowns that keep the landmarks where the winner has them, and ± 2√C_ii (clipped to the bounds) each
unknown's interval. A direction no landmark sees, or an interval that spans the bounds on both sides (a valley
the landmarks leave open: two unknowns that move them alike), leaves the unknown *not pinned*, as does an unknown
the search never moved (a short search's lines may not reach it; the others' intervals then hold it where it
is: ``given``). No extra simulation: only the maps the search evaluated (not the verify stage's, which run other
windows and noise).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from beambench.studies.twin_calibration.landmark_steps import fit_local_linear

if TYPE_CHECKING:
    from beambench.studies.twin_calibration.checks import TargetCheck
    from beambench.studies.twin_calibration.evaluate import Point
    from beambench.studies.unknowns import Unknown

NUMERIC_KINDS = ("transition", "speed")
UNSEEN = 1e-9  # eigenvalues of JᵀWJ below this × the largest: a direction the landmarks do not see


def intervals(
    checks: Sequence[TargetCheck], winner: Point, points: Sequence[Point], free: Sequence[Unknown]
) -> dict[str, Any]:
    """``{"method": …, "unknowns": {name: {"lo", "hi", "pinned"}}}`` (empty when the points pin no plane)."""
    marks = [c for c in checks if c.kind in NUMERIC_KINDS]
    points = [p for p in points if p.stage != "verify"] or list(points)  # one kind of map: the search's own
    # an unknown the search never moved (a short search: the first line only) is not pinned; the others are fitted
    moved = [u for u in free if len({round(u.coord(p.values[u.name]), 12) for p in points}) > 1]
    if not marks or not moved or len(points) < len(moved) + 3:
        return {}
    still = {u.name: {"lo": u.lo, "hi": u.hi, "pinned": False} for u in free if u not in moved}
    free = moved
    lo = np.array([u.bounds[0] for u in free])
    span = np.array([u.bounds[1] - u.bounds[0] for u in free])

    def unit(values: dict[str, float]) -> np.ndarray:
        return (np.array([u.coord(values[u.name]) for u in free]) - lo) / span

    x = np.array([unit(p.values) for p in points])
    y = np.array([[_nan(c.measure(p.steps)) for c in marks] for p in points])
    x0 = unit(winner.values)
    model = fit_local_linear(x, y, x0, scale=0.3)
    if not model.fitted.any():
        return {}
    jac = model.jacobian[model.fitted]
    sigma = np.array([max(c.tolerance, 1e-9) / 2.0 for c in marks])[model.fitted]
    fisher = (jac / sigma[:, None] ** 2).T @ jac
    w, v = np.linalg.eigh(fisher)
    seen = w > UNSEEN * max(float(w.max()), 1e-300)
    cov = (v[:, seen] / w[seen]) @ v[:, seen].T
    blind = np.abs(v[:, ~seen]).max(axis=1) > 0.1 if (~seen).any() else np.zeros(len(free), bool)
    out: dict[str, dict[str, Any]] = {}
    for i, u in enumerate(free):
        if blind[i]:
            out[u.name] = {"lo": u.lo, "hi": u.hi, "pinned": False}
            continue
        half = 2.0 * float(np.sqrt(max(cov[i, i], 0.0)))
        a, b = (max(0.0, x0[i] - half), min(1.0, x0[i] + half))
        pinned = not (a == 0.0 and b == 1.0)  # an interval that spans the box: a valley the landmarks leave open
        out[u.name] = {"lo": u.value(lo[i] + a * span[i]), "hi": u.value(lo[i] + b * span[i]), "pinned": pinned}
    return {
        "method": "local Jacobian of the landmarks ("
        + ", ".join(c.name for c, ok in zip(marks, model.fitted) if ok)
        + ") at the winner, each target's tolerance read as 2σ: ± 2σ, clipped to the bounds"
        + (f"; {', '.join(still)} not moved by the search: the other intervals hold them as found" if still else ""),
        "unknowns": {**({k: {**v, "given": list(still)} for k, v in out.items()} if still else out), **still},
    }


def landmark_spread(checks: Sequence[TargetCheck], near: Sequence[Point]) -> dict[str, dict[str, float]]:
    """The twin's numeric landmarks over the near-best points: ``{name: {"min", "max", "n"}}``."""
    out = {}
    for c in checks:
        if c.kind not in NUMERIC_KINDS:
            continue
        vals = [v for p in near if (v := c.measure(p.steps)) is not None and np.isfinite(v)]
        if vals:
            out[c.name] = {"min": float(min(vals)), "max": float(max(vals)), "n": len(vals)}
    return out


def _nan(v: float | None) -> float:
    return float("nan") if v is None else float(v)
