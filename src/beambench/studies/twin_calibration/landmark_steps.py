"""Landmark steps of the calibrator: a local linear model of a map's landmarks, solved for the targets'.

A rig's map has a few *landmarks* the targets name — the contact rig's continuous edge, lowest ½ and lowest ⅓,
the walker's speed at each target frequency. Each unknown moves several of them at once (the contact rig's
preload shifts all three, the sole's friction the continuous edge and, less, the others), so a target that
needs a diagonal move (more preload *and* less friction) sits in a valley that 1-D lines along the unknowns do
not leave. Every evaluated point tells where its landmarks are; a weighted linear fit of each landmark over the
points near the best one (Gaussian weights in the unit box of the free unknowns) gives the Jacobian, and a
trust-region Gauss–Newton step solves it for the target landmarks. The step is evaluated at a few lengths along
it; the trust region grows after a success and shrinks after a miss, as in any trust-region method.

Pure functions (:func:`fit_local_linear`, :func:`solve_step`) and the loop (:func:`landmark_steps`), which is
handed a narrow ``evaluate(values, frequencies, stage) -> points`` and the points evaluated so far.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

    from beambench.studies.twin_calibration.evaluate import Point
    from beambench.studies.unknowns import Unknown

# evaluate(values, frequencies, stage) -> one evaluated point per values, in order
Evaluate = Callable[[list[dict[str, float]], list[float], str], list["Point"]]

MIN_WEIGHT_POINTS = 1.5  # effective points beyond the model's parameters (d + 1) a landmark needs to be fitted


@dataclass(frozen=True)
class LinearModel:
    """Landmarks ≈ ``value + jacobian @ (x − x0)`` near ``x0`` (unit coordinates); ``fitted``: per landmark,
    whether enough evaluated points near ``x0`` have it."""

    value: np.ndarray  # (m,)
    jacobian: np.ndarray  # (m, d)
    fitted: np.ndarray  # (m,) bool


def fit_local_linear(x: np.ndarray, y: np.ndarray, x0: np.ndarray, scale: float) -> LinearModel:
    """Weighted least-squares plane of each column of ``y`` (n × m, NaN where a point lacks that landmark) over
    ``x`` (n × d unit coordinates), weights ``exp(−(|x − x0| / scale)²)``. A landmark is fitted when its points'
    effective number (Σw)² / Σw² exceeds d + 1 + :data:`MIN_WEIGHT_POINTS` and they span every direction."""
    n, d = x.shape
    m = y.shape[1]
    w = np.exp(-np.square(np.linalg.norm(x - x0, axis=1) / scale))
    value = np.full(m, np.nan)
    jac = np.zeros((m, d))
    fitted = np.zeros(m, bool)
    a = np.hstack([np.ones((n, 1)), x - x0])
    for k in range(m):
        ok = np.isfinite(y[:, k]) & (w > 1e-12)
        wk = w[ok]
        if wk.size == 0 or wk.sum() ** 2 / np.square(wk).sum() < d + 1 + MIN_WEIGHT_POINTS:
            continue
        sw = np.sqrt(wk)[:, None]
        ak = a[ok] * sw
        if np.linalg.matrix_rank(ak, tol=1e-6 * max(1.0, float(np.abs(ak).max()))) < d + 1:
            continue  # the points near x0 lie on a line or a plane: some direction is not seen
        coef, *_ = np.linalg.lstsq(ak, y[ok, k] * sw[:, 0], rcond=None)
        value[k], jac[k], fitted[k] = coef[0], coef[1:], True
    return LinearModel(value, jac, fitted)


def solve_step(model: LinearModel, target: np.ndarray, radius: float) -> np.ndarray:
    """The step s minimising |J s − (target − value)| over the fitted landmarks with |s| ≤ ``radius``
    (Levenberg–Marquardt: the damping that puts the step on the trust region's edge, found by bisection)."""
    keep = model.fitted & np.isfinite(target)
    d = model.jacobian.shape[1]
    if not keep.any():
        return np.zeros(d)
    jac, r = model.jacobian[keep], (target - model.value)[keep]
    step, *_ = np.linalg.lstsq(jac, r, rcond=None)
    if np.linalg.norm(step) <= radius:
        return np.asarray(step, float)
    jtj, jtr = jac.T @ jac, jac.T @ r

    def damped(lam: float) -> np.ndarray:
        return np.asarray(np.linalg.solve(jtj + lam * np.eye(d), jtr), float)

    lo, hi = 0.0, max(1e-9, float(np.trace(jtj)))
    while np.linalg.norm(damped(hi)) > radius:
        hi *= 10.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if np.linalg.norm(damped(mid)) > radius:
            lo = mid
        else:
            hi = mid
    return damped(hi)


@dataclass
class TrustRegion:
    """Radius (unit coordinates) of the step; grows ×1.6 after a success, halves after a miss."""

    radius: float = 0.2
    smallest: float = 0.02
    largest: float = 0.6

    def success(self) -> None:
        self.radius = min(self.largest, 1.6 * self.radius)

    def miss(self) -> None:
        self.radius *= 0.5

    @property
    def exhausted(self) -> bool:
        return self.radius < self.smallest


STEP_FRACTIONS = (0.5, 1.0, 0.75, 1.25)  # the lengths along the step evaluated per round (the first n of them)


@dataclass(frozen=True)
class LandmarkPlan:
    """How the landmark steps run: ``rounds`` trust-region steps, ``n`` points along each (evaluated on
    ``frequencies`` as ``stage``), until the best objective is ``good_enough`` or ``stop()``."""

    frequencies: list[float]
    stage: str
    rounds: int
    n: int
    good_enough: float
    stop: Callable[[], bool] = lambda: False


def landmark_steps(
    evaluate: Evaluate,
    seen: Sequence[Point],
    start: Point,
    free: Sequence[Unknown],
    landmarks: Callable[[pd.DataFrame], dict[str, tuple[float | None, float]]],
    plan: LandmarkPlan,
    on_round: Callable[[list[Point], float], None] | None = None,
) -> Point:
    """Up to ``plan.rounds`` trust-region steps from ``start``, each ``plan.n`` points along the model's step.
    The model is refitted each round over every point of ``seen`` (all evaluated so far, growing as the loop
    evaluates) of the plan's stage. Stops early when the best point's objective is ``plan.good_enough`` or every
    landmark is within half a unit of its target, when the model has no landmark left to move, or when
    ``plan.stop()``. ``landmarks(steps)``: a map's landmarks against its targets; ``on_round(points, radius)``
    after each round. Returns the best point seen."""
    lo = np.array([u.bounds[0] for u in free])
    span = np.array([u.bounds[1] - u.bounds[0] for u in free])

    def unit(p: Point) -> np.ndarray:
        return (np.array([u.coord(p.values[u.name]) for u in free]) - lo) / span

    found: dict[int, dict[str, tuple[float | None, float]]] = {}  # landmarks of each point, found once

    def of(p: Point) -> dict[str, tuple[float | None, float]]:
        if id(p) not in found:
            found[id(p)] = landmarks(p.steps)
        return found[id(p)]

    best, region = start, TrustRegion()
    names = list(of(start))
    target = np.array([of(start)[k][1] for k in names], float)
    for _ in range(plan.rounds):
        if plan.stop() or best.j <= plan.good_enough or region.exhausted or within(of(best), 0.5):
            break
        pts = [p for p in seen if p.stage == plan.stage and len(p.steps) == len(best.steps)]
        x = np.array([unit(p) for p in pts])
        y = np.array([[_nan(of(p)[k][0]) for k in names] for p in pts])
        x0 = unit(best)
        model = fit_local_linear(x, y, x0, scale=max(0.15, 1.5 * region.radius))
        step = solve_step(model, target, region.radius)
        if not model.fitted.any() or np.linalg.norm(step) < 1e-3:
            break
        cands = [np.clip(x0 + f * step, 0.0, 1.0) for f in STEP_FRACTIONS[: max(1, plan.n)]]
        values = [
            {**best.values, **{u.name: u.value(float(lo[i] + c[i] * span[i])) for i, u in enumerate(free)}}
            for c in cands
        ]
        got = evaluate(values, plan.frequencies, plan.stage)
        if on_round is not None:
            on_round(got, region.radius)
        winner = min(got, key=lambda p: p.j)
        if winner.j < best.j - 1e-9:
            best = winner
            region.success()
        else:
            region.miss()
    return best


def within(landmarks: dict[str, tuple[float | None, float]], tolerance: float) -> bool:
    """Does the map have every landmark, each within ``tolerance`` of its target? (False when none is named.)"""
    return bool(landmarks) and all(v is not None and abs(v - t) <= tolerance for v, t in landmarks.values())


def _nan(v: Any) -> float:
    return float("nan") if v is None else float(v)
