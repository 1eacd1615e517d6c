"""Drift from reference steps: a linear trend per hour of each reference-step result, tested against the
step-to-step noise, and an optional drift correction of the sweep steps.

A protocol's ``reference: {frequency_hz, every_steps}`` repeats one condition first, after every N sweep steps
and last; whatever changes between those repeats is the rig changing (a beam warming up), not the frequency.

**Trend** (:func:`drift_table`): for each metric in :data:`DRIFT_METRICS`, an ordinary least-squares line
y = a + b·t through the reference steps, t the middle of each record window in hours from the first one. The
slope b is the trend per hour; its standard error SE(b) = s/√Σ(t − t̄)², s the residual standard deviation
about the line (the step-to-step noise, n − 2 degrees of freedom). The trend is **significant** when both

- ``|b|/SE(b) > t(0.975, n − 2)``: the two-sided 5 % t-test of a zero slope (≈ 2 for ten or more reference
  steps; larger for few), and
- ``|b|·span > resolution``: the change over the session exceeds what the analysis resolves of that metric
  (:data:`RESOLUTION`; contacts per cycle: one touchdown in a record window, 1/N for N drive cycles). Without
  it a noiseless simulation (s → 0) would call a numerically tiny trend significant.

Three reference steps at least; fewer give NaN and ``significant`` false.

**Correction** (:func:`drift_corrected`, on request): each sweep step's value minus the drift at its time,
the reference's value linearly interpolated between the two reference steps that bracket it, less the first
reference value (so corrected values are on the scale of the start of the session; steps after the last
reference hold its value). Additive; it assumes the drift at the reference frequency applies at every frequency.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import special  # Student's t (stdtrit, stdtr): scipy.stats costs ~1 s to import

DRIFT_METRICS = {
    "contacts_per_cycle": "contacts per cycle",
    "peak_normal_n": "peak normal force (N)",
    "tip_major_mm": "tip ellipse major (mm)",
    "tip_minor_mm": "tip ellipse minor (mm)",
    "motor_current_rms_a": "motor current RMS (A)",
}
# the smallest change over a session the analysis resolves per metric (contacts per cycle: per step, 1/N)
RESOLUTION = {"peak_normal_n": 0.005, "tip_major_mm": 0.005, "tip_minor_mm": 0.005, "motor_current_rms_a": 0.002}
DRIFT_COLUMNS = [
    "metric",
    "n_reference",
    "mean",
    "trend_per_h",
    "trend_se_per_h",
    "t_stat",
    "t_crit",
    "p_value",
    "noise_std",
    "span_h",
    "change",
    "resolution",
    "significant",
]


def reference_steps(table: pd.DataFrame) -> pd.DataFrame:
    """The reference steps of a per-step table with ``t_h``: record-window middles in hours from the first."""
    if "kind" not in table or "t_settled_s" not in table:
        return table.iloc[0:0].assign(t_h=pd.Series(dtype=float))
    ref = table[table["kind"] == "reference"].copy()
    mid = ref["t_settled_s"] + ref["record_s"].fillna(0.0) / 2
    return ref.assign(t_h=(mid - mid.min()) / 3600.0).sort_values("t_h", kind="stable")


def _resolution(metric: str, ref: pd.DataFrame) -> float:
    if metric == "contacts_per_cycle":
        cycles = (ref["record_s"] * ref.get("analysis_frequency_hz", ref["frequency_hz"])).median()
        return float(1.0 / cycles) if np.isfinite(cycles) and cycles > 0 else np.nan
    return RESOLUTION.get(metric, 0.0)


def linear_trend(t_h: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """OLS slope (per hour), its standard error, t statistic, critical t and p (two-sided), residual std."""
    ok = np.isfinite(t_h) & np.isfinite(y)
    t, v = t_h[ok], y[ok]
    n = len(t)
    out = dict(n_reference=float(n), mean=float(np.mean(v)) if n else np.nan)
    nan = dict.fromkeys(("trend_per_h", "trend_se_per_h", "t_stat", "t_crit", "p_value", "noise_std"), np.nan)
    sxx = float(np.sum((t - t.mean()) ** 2)) if n else 0.0
    if n < 3 or sxx <= 0:
        return {**out, **nan, "span_h": float(np.ptp(t)) if n else np.nan}
    b = float(np.sum((t - t.mean()) * (v - v.mean())) / sxx)
    resid = v - (v.mean() + b * (t - t.mean()))
    s = float(np.sqrt(np.sum(resid**2) / (n - 2)))
    se = s / np.sqrt(sxx)
    tstat = b / se if se > 0 else (np.inf if b != 0 else 0.0)
    return {
        **out,
        "trend_per_h": b,
        "trend_se_per_h": se,
        "t_stat": float(tstat),
        "t_crit": float(special.stdtrit(n - 2, 0.975)),  # = stats.t.ppf(0.975, n - 2)
        "p_value": float(2 * special.stdtr(n - 2, -abs(tstat))),  # = 2 * stats.t.sf(|t|, n - 2)
        "noise_std": s,
        "span_h": float(np.ptp(t)),
    }


def drift_table(table: pd.DataFrame) -> pd.DataFrame:
    """One row per metric of :data:`DRIFT_METRICS` present: trend per hour at the reference steps, its standard
    error and whether it exceeds the step-to-step noise (module docstring); empty without reference steps."""
    ref = reference_steps(table)
    rows = []
    for metric in (m for m in DRIFT_METRICS if m in ref):
        y = ref[metric].astype(float).to_numpy()
        if not np.isfinite(y).any():
            continue
        r = linear_trend(ref["t_h"].to_numpy(float), y)
        change = abs(r["trend_per_h"] * r["span_h"])
        res = _resolution(metric, ref)
        sig = bool(np.isfinite(r["t_stat"]) and abs(r["t_stat"]) > r["t_crit"] and change > (res or 0.0))
        rows.append({"metric": metric, **r, "change": change, "resolution": res, "significant": sig})
    return pd.DataFrame(rows, columns=DRIFT_COLUMNS)


def drift_corrected(table: pd.DataFrame, metrics: tuple[str, ...] = tuple(DRIFT_METRICS)) -> pd.DataFrame:
    """``table`` with ``<metric>_drift_corrected`` for every metric with two or more reference values: the value
    less the reference's drift since the first reference step, linearly interpolated in time (module docstring)."""
    ref = reference_steps(table)
    out = table.copy()
    if len(ref) < 2:
        return out
    t0 = float((ref["t_settled_s"] + ref["record_s"].fillna(0.0) / 2).min())
    t_h = ((out["t_settled_s"] + out["record_s"].fillna(0.0) / 2) - t0).to_numpy(float) / 3600.0
    for m in (m for m in metrics if m in ref):
        ok = ref[m].notna().to_numpy()
        if ok.sum() < 2:
            continue
        rt, rv = ref["t_h"].to_numpy(float)[ok], ref[m].to_numpy(float)[ok]
        drift = np.interp(t_h, rt, rv) - rv[0]
        out[f"{m}_drift_corrected"] = out[m].astype(float) - drift
    return out
