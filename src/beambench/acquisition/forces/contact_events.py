"""Contact events from the plate's normal force: hysteresis threshold, minimum durations, ratio and regime.

The contact regime (paper Sec. IV-A, Figs. 1b and 4) comes from the load cells' normal force ALONE, as the
paper's does. A contact starts when the normal force rises above ``on`` and ends when it falls below ``off``
(< ``on``); both scale with the force noise (``noise_factor``·σ, at least ``floor_n``). Blips shorter than
``min_contact_s`` are ignored. A *flight* (the foot off the plate between two contacts) only counts when it
lasts more than ``min_flight_fraction`` of a drive period (counted in whole samples, so that the time stamps'
rounding does not decide a flight of exactly that length): a soft contact chatters (on/off ~1000×/s while the
foot stays down), and such gaps are merged into the contact. The contact ratio is flights (touchdowns) per
drive cycle; the regime labels it ``"1"``, ``"1/2"``, ``"1/3"``…, ``"2"``…, ``"continuous"`` (in contact for
at least ``continuous_fraction`` of the window, no flight), ``"none"`` or ``"irregular"``.

No foot-height test by default: the mocap's 0.1 mm noise is larger than the foot's rise in a chattering
contact, so a height criterion made the label depend on the noise. :func:`detect_contacts` still accepts a
foot height for callers that have a clean one.

Pure numpy; it lives below both the simulator and the analysis so that both classify the same way
(:func:`beambench.analysis.contact.force_regime` is this module's :func:`force_regime`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np


@dataclass(frozen=True)
class ContactParams:
    """Thresholds in newtons (None: from the noise, ``noise_factor``·σ, at least ``floor_n``) and durations."""

    on_n: float | None = None
    off_n: float | None = None
    noise_factor: float = 8.0
    floor_n: float = 0.02
    min_contact_s: float = 0.0005
    min_flight_fraction: float = 0.10
    min_rise_m: float = 20e-6
    continuous_fraction: float = 0.95
    regime_tolerance: float = 0.12
    max_subharmonic: int = 6


@dataclass
class Contacts:
    """Contact intervals (seconds, same clock as the input) of one record window, after merging."""

    start_s: np.ndarray
    end_s: np.ndarray
    touchdown: np.ndarray  # bool per interval: began after a counted flight inside the window
    on_n: float
    off_n: float
    duration_s: float
    in_contact_fraction: float
    mask: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, bool))  # per input sample

    @property
    def touchdown_s(self) -> np.ndarray:
        return self.start_s[self.touchdown]

    @property
    def n_touchdowns(self) -> int:
        return int(self.touchdown.sum())


def runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start (inclusive) and end (exclusive) indices of the runs of True in a boolean array."""
    m = np.asarray(mask, bool).astype(np.int8)
    d = np.diff(np.concatenate([[0], m, [0]]))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def noise_sigma(x: np.ndarray) -> float:
    """Robust white-noise σ from first differences (insensitive to slow signal and to sparse spikes)."""
    d = np.diff(np.asarray(x, float)[np.isfinite(x)])
    if len(d) < 4:
        return 0.0
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2))


def off_plate_sigma(x: np.ndarray, floor: float, factor: float = 8.0, iterations: int = 3) -> float:
    """The force noise σ measured where the foot is off the plate: first differences of consecutive samples
    that are both below the current threshold (starting at ``floor``, then ``factor``·σ). A chattering
    contact's on/off jumps would inflate a σ taken over the whole window (and raise the threshold above the
    contact force); a window in contact throughout has no such pairs and gives 0 (the floor decides)."""
    v = np.asarray(x, float)
    v = v[np.isfinite(v)]
    sigma = 0.0
    for _ in range(iterations):
        below = v < max(floor, factor * sigma)
        pair = below[:-1] & below[1:]
        d = np.diff(v)[pair]
        if len(d) < 8:
            return sigma
        new = float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2))
        if abs(new - sigma) <= 0.01 * new:
            return new
        sigma = new
    return sigma


def hysteresis(x: np.ndarray, on: float, off: float) -> np.ndarray:
    """Boolean state: True once ``x > on``, False once ``x < off``; holds in between (starts False)."""
    x = np.asarray(x, float)
    state = np.where(x > on, 1, np.where(x < off, 0, -1))
    idx = np.where(state >= 0, np.arange(len(x)), -1)
    np.maximum.accumulate(idx, out=idx)
    out = np.zeros(len(x), bool)
    have = idx >= 0
    out[have] = state[idx[have]] == 1
    return out


def detect_contacts(
    t_s: np.ndarray,
    normal_n: np.ndarray,
    drive_hz: float,
    params: ContactParams = ContactParams(),
    *,
    foot_t_s: np.ndarray | None = None,
    foot_height_m: np.ndarray | None = None,
) -> Contacts:
    """Find contacts in one record window of normal force (N, positive = pressing on the plate).

    Missing samples (NaN) are dropped; the state holds across them. ``foot_height_m`` (with ``foot_t_s``) is
    the foot's height along the up axis, used for the rise criterion of flights.
    """
    t = np.asarray(t_s, float)
    fn = np.asarray(normal_n, float)
    ok = np.isfinite(t) & np.isfinite(fn)
    n_in = len(t)
    t, fn = t[ok], fn[ok]
    dur = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    sigma = off_plate_sigma(fn, params.floor_n, params.noise_factor)
    on = params.on_n if params.on_n is not None else max(params.noise_factor * sigma, params.floor_n)
    off = params.off_n if params.off_n is not None else 0.5 * on
    empty = Contacts(np.zeros(0), np.zeros(0), np.zeros(0, bool), on, off, dur, 0.0, np.zeros(n_in, bool))
    if len(t) < 2:
        return empty
    state = hysteresis(fn, on, off)
    starts, ends = runs(state)
    if len(starts) == 0:
        return empty
    # interval times: from the first sample in contact to the first sample out of contact
    t_end_ext = np.append(t, t[-1])
    cs, ce = t[starts], t_end_ext[ends]
    keep = (ce - cs) >= params.min_contact_s
    # the first/last interval may be cut by the window: keep them even if short
    keep |= (starts == 0) | (ends == len(t))
    cs, ce, si, ei = cs[keep], ce[keep], starts[keep], ends[keep]
    if len(cs) == 0:
        return empty
    period = 1.0 / drive_hz if drive_hz and np.isfinite(drive_hz) and drive_hz > 0 else 0.0
    # a flight is counted in whole samples (from the first sample out of contact to the first one back, rounded to
    # the nearest sample interval) against the threshold in samples: the time stamps' rounding and jitter below half
    # a sample cannot decide it (compared in seconds, a flight of exactly the threshold counted or not by rounding)
    sample_s = max(float(np.median(np.diff(t))), 1e-12)
    min_flight = params.min_flight_fraction * period / sample_s  # samples; a whole number where within 0.05 of one
    min_flight = (round(min_flight) if abs(min_flight - round(min_flight)) < 0.05 else min_flight) + 1e-6

    def samples(span_s: float) -> int:
        return round(span_s / sample_s)

    rise_ok = None
    if foot_height_m is not None and foot_t_s is not None:
        ft = np.asarray(foot_t_s, float)
        fh = np.asarray(foot_height_m, float)
        good = np.isfinite(ft) & np.isfinite(fh)
        ft, fh = ft[good], fh[good]
        if len(ft) > 2:
            in_c = np.zeros(len(ft), bool)
            for a, b in zip(cs, ce):
                in_c |= (ft >= a) & (ft < b)
            base = float(np.median(fh[in_c])) if in_c.any() else float(np.min(fh))
            rise_ok = (ft, fh, base)

    # merge contacts separated by flights that do not count
    m_start, m_end = [cs[0]], [ce[0]]
    counted = [bool(si[0] > 0)]  # a contact already on at the window start was not seen touching down
    for a, b in zip(cs[1:], ce[1:]):
        gap_from, gap_to = m_end[-1], a
        real = samples(gap_to - gap_from) > min_flight
        if real and rise_ok is not None:
            ft, fh, base = rise_ok
            sel = (ft >= gap_from) & (ft <= gap_to)
            if sel.any():
                real = float(np.max(fh[sel]) - base) > params.min_rise_m
        if real:
            m_start.append(a)
            m_end.append(b)
            counted.append(True)
        else:
            m_end[-1] = b
    start, end = np.asarray(m_start), np.asarray(m_end)
    touchdown = np.asarray(counted, bool)
    if touchdown[0] and samples(start[0] - t[0]) <= min_flight:
        touchdown[0] = False  # began so close to the window start that its flight was not seen
    sub = np.zeros(len(t), bool)
    for a, b in zip(si, ei):
        sub[a:b] = True
    mask = np.zeros(n_in, bool)
    mask[ok] = sub
    frac = float(np.sum(np.clip(end, t[0], t[-1]) - np.clip(start, t[0], t[-1])) / dur) if dur > 0 else 0.0
    return Contacts(start, end, touchdown, on, off, dur, frac, mask)


@dataclass(frozen=True)
class ContactSummary:
    """Per-step contact figures: counts, frequency (Hz), ratio (touchdowns per drive cycle) and regime."""

    n_contacts: int
    contact_frequency_hz: float
    contacts_per_cycle: float
    regime: str
    in_contact_fraction: float


def regime_label(
    ratio: float, in_contact_fraction: float, n_intervals: int, params: ContactParams = ContactParams()
) -> str:
    """Label a contact ratio: ``"none"``, ``"continuous"``, ``"1"``, ``"1/2"``… ``"2"``… or ``"irregular"``."""
    if n_intervals == 0:
        return "none"
    if (not np.isfinite(ratio) or ratio == 0) and in_contact_fraction >= params.continuous_fraction:
        return "continuous"
    if not np.isfinite(ratio) or ratio <= 0:
        return "irregular"
    if ratio <= 1.0 + params.regime_tolerance:
        k = max(1, round(1.0 / ratio))
        if k <= params.max_subharmonic and abs(ratio * k - 1.0) <= params.regime_tolerance:
            return str(Fraction(1, k))
        return "irregular"
    k = round(ratio)
    return str(k) if abs(ratio / k - 1.0) <= params.regime_tolerance else "irregular"


def summarize_contacts(c: Contacts, drive_hz: float, params: ContactParams = ContactParams()) -> ContactSummary:
    """Contact frequency and ratio from the touchdowns of one window, and its regime label."""
    n = c.n_touchdowns
    if c.duration_s <= 0 or not drive_hz > 0:
        return ContactSummary(
            n, float("nan"), float("nan"), "none" if len(c.start_s) == 0 else "irregular", c.in_contact_fraction
        )
    cf = n / c.duration_s
    ratio = cf / drive_hz
    if len(c.start_s) > 0 and n <= 1 and c.in_contact_fraction >= params.continuous_fraction:
        label = "continuous"  # on the plate the whole window (at most one touchdown, right at its start)
    elif n == 0 and len(c.start_s) > 0:
        label = "irregular"
    else:
        label = regime_label(ratio, c.in_contact_fraction, len(c.start_s), params)
    return ContactSummary(n, cf, ratio, label, c.in_contact_fraction)


REGIME_ORDER = ["none", "continuous", "3", "2", "1", "1/2", "1/3", "1/4", "1/5", "1/6", "irregular"]


def regime_fraction(label: str) -> float:
    """Numeric contacts-per-cycle of a label (NaN for none/continuous/irregular)."""
    try:
        return float(Fraction(label))
    except (ValueError, ZeroDivisionError):
        return float("nan")


def force_contacts(
    t_s: np.ndarray, normal_n: np.ndarray, drive_hz: float, params: ContactParams = ContactParams()
) -> tuple[Contacts, ContactSummary]:
    """Contacts and their summary of one record window from the normal force alone (no foot height)."""
    c = detect_contacts(t_s, normal_n, drive_hz, params)
    return c, summarize_contacts(c, drive_hz, params)


def force_regime(
    t_s: np.ndarray, normal_n: np.ndarray, drive_hz: float, params: ContactParams = ContactParams()
) -> ContactSummary:
    """The contact regime of one record window from the plate's normal force alone (N, positive = pressing).

    Returns a :class:`ContactSummary`: ``contacts_per_cycle`` (touchdowns per drive cycle; 0 for continuous
    contact) and ``regime`` (``none``, ``continuous``, ``1``, ``1/2``, ``1/3``…, ``2``…, ``irregular``)."""
    return force_contacts(t_s, normal_n, drive_hz, params)[1]
