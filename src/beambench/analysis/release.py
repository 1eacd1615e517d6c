"""The release test (paper Sec. II-B, Fig. 2k) read as a second-order system: the tip, held deflected by a
load, is let go and returns to rest; its free response gives the natural frequency and the damping ratio.

The displacement is the tip markers' mean relative to the clamp (stage) marker, minus its rest position at the
end of the record, projected on the direction of the loaded deflection. After the release instant it is fitted
with the free response of ``x'' + 2ζω x' + ω² x = 0`` released from rest at ``x0``, which covers the under-,
critically and over-damped cases alike (an over-damped beam has a natural frequency but no oscillation). A
strongly over-damped decay (ζ ≳ 2) shows little more than its slow pole ω(ζ − √(ζ² − 1)), so ω and ζ are then
poorly determined one by one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import SessionAnalysis, StepResult

TIP_PREFIX = "tip"
REST_SHARE = 0.3  # the last 30 % of the record is the rest position
SETTLED = 0.05  # settled once within 5 % of the initial deflection (and staying there)


@dataclass(frozen=True)
class TipDisplacement:
    """Tip displacement from rest (mm) at ``t`` (s from the record window's start): ``xyz`` [n, 3] (world axes)
    and ``along`` [n], its component along the loaded deflection."""

    t: np.ndarray
    xyz: np.ndarray
    along: np.ndarray
    markers: tuple[str, ...]


@dataclass(frozen=True)
class Decay:
    """The fitted free response: release instant (s from the window start), deflection at release (mm),
    natural frequency ω/2π (Hz), damping ratio ζ, damped frequency (Hz, NaN when ζ ≥ 1), 5 % settling time
    after the release (ms, measured), the fit's R² and the number of samples fitted."""

    release_s: float
    deflection_mm: float
    natural_frequency_hz: float
    damping_ratio: float
    damped_frequency_hz: float
    settling_ms: float
    r2: float
    n: int

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """The fitted displacement (mm) at ``t`` (s from the window start): the hold before the release."""
        tau = np.asarray(t, float) - self.release_s
        x = free_response(np.maximum(tau, 0.0), self.deflection_mm, self.natural_frequency_hz, self.damping_ratio)
        return np.where(tau < 0, self.deflection_mm, x)


NAN_DECAY = Decay(*(float("nan"),) * 7, 0)


def tip_displacement(t: np.ndarray, markers: dict[str, np.ndarray], clamp: str = "stage") -> TipDisplacement | None:
    """The tip markers' (``tip*``) mean relative to the clamp marker, from its rest position, in mm; None if the
    session has no tip markers."""
    tips = tuple(sorted(m for m in markers if m.startswith(TIP_PREFIX)))
    if not tips or len(t) < 10:
        return None
    p = np.nanmean(np.stack([markers[m] for m in tips]), axis=0)
    if clamp in markers:
        p = p - markers[clamp]
    p = p * 1e3
    rest = np.nanmedian(p[int(len(p) * (1 - REST_SHARE)) :], axis=0)
    d = p - rest
    hold = np.nanmedian(d[: max(3, len(d) // 20)], axis=0)
    norm = float(np.linalg.norm(hold))
    u = hold / norm if norm > 0 else np.array([0.0, 0.0, 1.0])
    return TipDisplacement(np.asarray(t, float), d, d @ u, tips)


def free_response(tau: np.ndarray, x0: float, fn_hz: float, zeta: float) -> np.ndarray:
    """``x(τ)`` of a second-order system released from rest at ``x0`` (any ζ > 0)."""
    w = 2 * math.pi * fn_hz
    tau = np.asarray(tau, float)
    if abs(zeta - 1.0) < 1e-6:
        return x0 * (1 + w * tau) * np.exp(-w * tau)
    root = np.sqrt(complex(zeta * zeta - 1.0))
    s1, s2 = w * (-zeta + root), w * (-zeta - root)
    return np.real(x0 * (s1 * np.exp(s2 * tau) - s2 * np.exp(s1 * tau)) / (s1 - s2))


def find_release(t: np.ndarray, x: np.ndarray, hold_share: float = 0.08) -> float:
    """The release instant (s): the last sample of the loaded hold before ``x`` first leaves it by more than
    10 noise σ (at least a tenth of the deflection); NaN if it never does."""
    n0 = max(5, int(len(t) * hold_share))
    hold = float(np.nanmedian(x[:n0]))
    sigma = 1.4826 * float(np.nanmedian(np.abs(np.diff(x[:n0])))) / math.sqrt(2)
    moved = np.flatnonzero(np.abs(x - hold) > max(10 * sigma, 0.1 * abs(hold)))
    return float(t[max(int(moved[0]) - 1, 0)]) if len(moved) else float("nan")


def fit_decay(t: np.ndarray, x: np.ndarray) -> Decay:
    """Fit the free response to the displacement ``x`` (mm) after its release (release instant, deflection,
    natural frequency, damping ratio by least squares; the rest is the zero of ``x``)."""
    from scipy.optimize import least_squares

    t, x = np.asarray(t, float), np.asarray(x, float)
    ok = np.isfinite(t) & np.isfinite(x)
    t, x = t[ok], x[ok]
    t_rel = find_release(t, x) if len(t) > 10 else float("nan")
    if not np.isfinite(t_rel):
        return NAN_DECAY
    dt = float(np.median(np.diff(t)))
    x0 = float(np.nanmedian(x[(t <= t_rel) & (t > t_rel - 0.05)]))
    sel = t >= t_rel - 2 * dt
    ts, xs = t[sel], x[sel]
    settling = _settling_s(ts - t_rel, xs, x0)
    guess_fn = 1.0 / (2 * max(settling, 4 * dt))

    def resid(p: np.ndarray) -> np.ndarray:
        return Decay(p[0], p[1], math.exp(p[2]), math.exp(p[3]), 0, 0, 0, 0)(ts) - xs

    best = None
    for zeta in (0.05, 0.3, 1.0, 3.0):  # the damping decides the shape: start from each regime
        p0 = [t_rel + 0.5 * dt, x0, math.log(guess_fn), math.log(zeta)]
        lo = [t_rel - 2 * dt, x0 - 3 * abs(x0), math.log(0.1), math.log(1e-3)]
        hi = [t_rel + 2 * dt, x0 + 3 * abs(x0), math.log(2.0 / dt), math.log(50.0)]
        fit = least_squares(resid, p0, bounds=(lo, hi), x_scale="jac")
        if best is None or fit.cost < best.cost:
            best = fit
    assert best is not None
    p = best.x
    fn, zeta = math.exp(p[2]), math.exp(p[3])
    ss = float(((xs - xs.mean()) ** 2).sum())
    r2 = 1 - 2 * float(best.cost) / ss if ss > 0 else float("nan")
    fd = fn * math.sqrt(1 - zeta * zeta) if zeta < 1 else float("nan")
    return Decay(float(p[0]), float(p[1]), fn, zeta, fd, settling * 1e3, r2, len(ts))


def _settling_s(tau: np.ndarray, x: np.ndarray, x0: float) -> float:
    """Time after the release from which ``|x|`` stays within ``SETTLED`` of ``|x0|`` (or 3 noise σ of the rest)."""
    tail = x[tau > 0.7 * tau[-1]] if len(tau) else x
    sigma = float(np.nanstd(tail)) if len(tail) > 3 else 0.0
    band = max(SETTLED * abs(x0), 3 * sigma)
    outside = np.flatnonzero((np.abs(x) > band) & (tau >= 0))
    return float(tau[min(outside[-1] + 1, len(tau) - 1)]) if len(outside) else 0.0


def step_decay(r: StepResult) -> tuple[TipDisplacement, Decay] | None:
    """A release step's tip displacement and its fitted decay; None without tip markers."""
    d = tip_displacement(r.t_mocap, r.markers)
    return None if d is None else (d, fit_decay(d.t, d.along))


RELEASE_COLUMNS = {
    "step": "step",
    "markers": "tip markers",
    "release_s": "release (s into the record)",
    "deflection_mm": "deflection at release (mm)",
    "natural_frequency_hz": "natural frequency (Hz)",
    "damping_ratio": "damping ratio ζ",
    "damped_frequency_hz": "damped frequency (Hz)",
    "settling_ms": "settling to 5 % (ms)",
    "r2": "fit R²",
    "n": "samples fitted",
}


def release_table(a: SessionAnalysis) -> pd.DataFrame:
    """One row per step with tip markers: the decay fit, with units in the headers (damped frequency blank when
    the beam is over-damped)."""
    rows = []
    for r in a.steps:
        fit = step_decay(r)
        if fit is None:
            continue
        d, decay = fit
        rows.append({"step": r.index, "markers": ", ".join(d.markers), **vars(decay)})
    return pd.DataFrame(rows, columns=list(RELEASE_COLUMNS)).rename(columns=RELEASE_COLUMNS)
