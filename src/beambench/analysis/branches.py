"""Sweep branches and repeats in the per-step table: spread of repeated steps and up/down hysteresis flags.

Each step row carries ``direction`` (up/down), ``kind`` (sweep/reference) and ``repeat`` from ``/steps`` (sessions
recorded before these existed read as up, sweep, 0). Sweep steps of one frequency and direction are a *group*:

- **Spread** (when some group has two or more repeats): for each metric in :data:`SPREAD_METRICS`, the group's
  ``<metric>_mean``, ``<metric>_std`` (sample standard deviation, ddof = 1) and a 95 % interval of the mean,
  ``<metric>_ci95_lo``/``_hi`` = mean ± t(0.975, n − 1)·std/√n (Student's t); a group of one has NaN spread.
- **Noise of contacts per cycle** (``contacts_per_cycle_noise``): σ = √((1/N)² + s²/n), with N the drive cycles
  in a record window (one touchdown more or less in the window changes contacts per cycle by 1/N) and s the
  repeats' std over n repeats (0 for one repeat).
- **Repeatability**: ``repeats_agree`` is false where a group's repeats do not all share one regime.
- **Hysteresis** (when a frequency has both branches): ``hysteresis`` is true where no regime occurs on both
  branches, or their mean contacts per cycle differ by more than 2·√(σ_up² + σ_down²) (``hysteresis_limit``);
  ``hysteresis_delta`` = down − up contacts per cycle; ``hysteresis_why`` says which test fired.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
from scipy import special  # Student's t through special.stdtrit: scipy.stats costs ~1 s to import

from beambench.acquisition.protocol.plan import Step

SPREAD_METRICS = (
    "contacts_per_cycle",
    "contact_frequency_hz",
    "peak_normal_n",
    "tip_major_mm",
    "tip_minor_mm",
    "body_speed_mm_s",
)
COVERAGE = 2.0  # hysteresis: the branches differ by more than this many standard errors of their difference


def with_step_labels(steps: pd.DataFrame) -> pd.DataFrame:
    """``/steps`` with a direction, kind and repeat on every row: a session recorded without them (or with an
    empty label) takes the step plan's defaults (:class:`~beambench.acquisition.protocol.plan.Step`)."""
    blank = Step(index=0, frequency_hz=0.0, settle_s=0.0, record_s=0.0)
    defaults: dict[str, str | int] = {"direction": blank.direction, "kind": blank.kind, "repeat": blank.repeat}
    out = steps.copy()
    for name, default in defaults.items():
        if name not in out:
            out[name] = default
        elif isinstance(default, str):
            out[name] = out[name].replace("", default)
    return out


def most_common(values: pd.Series) -> str:
    """The most frequent label (a group's regime)."""
    counts = values.astype(str).value_counts()
    return str(counts.index[0]) if len(counts) else ""


def _cycles(t: pd.DataFrame) -> pd.Series:
    f = t["analysis_frequency_hz"] if "analysis_frequency_hz" in t else t["frequency_hz"]
    return (t["record_s"] * f).where(lambda n: n > 0)


def _spread(t: pd.DataFrame, groups: Any) -> pd.DataFrame:
    for m in (m for m in SPREAD_METRICS if m in t):
        g = groups[m]
        n = g.transform("count")
        mean, std = g.transform("mean"), g.transform("std")
        half = special.stdtrit((n - 1).clip(lower=1), 0.975) * std / np.sqrt(n)  # = stats.t.ppf(0.975, n - 1)
        half = half.where(n > 1)
        t[f"{m}_mean"], t[f"{m}_std"] = mean, std.where(n > 1)
        t[f"{m}_ci95_lo"], t[f"{m}_ci95_hi"] = mean - half, mean + half
    return t


def _noise(t: pd.DataFrame, groups: Any) -> pd.Series:
    """σ of a group's mean contacts per cycle: window quantisation and the repeats' scatter."""
    n = groups["contacts_per_cycle"].transform("count")
    s = groups["contacts_per_cycle"].transform("std").fillna(0.0)
    quant = 1.0 / _cycles(t)
    return pd.Series(np.sqrt(quant**2 + s**2 / n.clip(lower=1)), index=t.index)


def _hysteresis(t: pd.DataFrame, sweep: pd.Series) -> pd.DataFrame:
    t["hysteresis"] = False
    t["hysteresis_delta"] = np.nan
    t["hysteresis_limit"] = np.nan
    t["hysteresis_why"] = ""
    for _f, at in t[sweep].groupby("frequency_hz"):
        up, down = at[at["direction"] == "up"], at[at["direction"] == "down"]
        if up.empty or down.empty:
            continue
        ru, rd = most_common(up["regime"]), most_common(down["regime"])
        shared = set(up["regime"].astype(str)) & set(down["regime"].astype(str))
        delta = float(down["contacts_per_cycle"].mean() - up["contacts_per_cycle"].mean())
        sig_u = float(up["contacts_per_cycle_noise"].iloc[0])
        sig_d = float(down["contacts_per_cycle_noise"].iloc[0])
        limit = COVERAGE * float(np.hypot(sig_u, sig_d))
        why = []
        if not shared:
            why.append(f"regime {ru or '?'} up, {rd or '?'} down")
        if np.isfinite(delta) and np.isfinite(limit) and abs(delta) > limit:
            why.append(f"contacts/cycle differ by {delta:+.3f} (> {limit:.3f})")
        idx = at.index
        t.loc[idx, "hysteresis"] = bool(why)
        t.loc[idx, "hysteresis_delta"] = delta
        t.loc[idx, "hysteresis_limit"] = limit
        t.loc[idx, "hysteresis_why"] = "; ".join(why)
    return t


def annotate_branches(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` with spread columns (if any frequency was repeated) and hysteresis flags (if a frequency was
    swept both ways); reference steps are left out of both."""
    t = table.copy()
    if t.empty or "direction" not in t or "frequency_hz" not in t:
        return t
    sweep = t["kind"] == "sweep"
    if not sweep.any():
        return t
    by = ["frequency_hz", "direction"]
    if int(t[sweep].groupby(by).size().max()) > 1:
        sub = _spread(t[sweep].copy(), t[sweep].groupby(by))
        t = t.join(sub[[c for c in sub.columns if c not in t.columns]])
    if "regime" in t:
        n_regimes = t[sweep].groupby(by)["regime"].transform(lambda r: r.astype(str).nunique())
        t.loc[sweep, "repeats_agree"] = n_regimes == 1
    if "contacts_per_cycle" in t:
        s = t[sweep]
        t.loc[sweep, "contacts_per_cycle_noise"] = _noise(s, s.groupby(by))
        if {"up", "down"} <= set(s["direction"]):
            t = _hysteresis(t, sweep)
    return t
