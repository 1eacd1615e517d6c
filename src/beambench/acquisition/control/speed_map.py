"""A walker's speed map (measured speed vs drive frequency) and the bands a speed controller may use (pure).

A *band* is a frequency interval over which the measured speed is strictly monotonic in frequency, every point
regular, and the speed of one sign (forward > 0, backward < 0): inside it a target speed has exactly one
frequency (linear interpolation between the map's points), and feedback can move the frequency without the
speed's sign or slope changing under it. A band ends at the first point where the speed stops rising (or
falling), at an irregular point, or where the speed crosses zero (the crossing, interpolated, is its edge:
speed 0 there). Points above the protocol's frequency limit are never used.

A point is *irregular* when the map says so (a ``regime`` containing ``irregular``) or its speed's standard
error exceeds :data:`IRREGULAR_STDERR_FACTOR` times the map's median (a gait that does not repeat cycle to
cycle: the walker twin above ~75 Hz).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

IRREGULAR_STDERR_FACTOR = 2.0  # stderr above this many times the map's median: the gait is irregular there
MIN_BAND_SPAN_MM_S = 5.0  # a band whose speeds span less than this (mm/s) is not worth controlling in


class SpeedMapError(ValueError):
    """The map cannot be used (too few points, no band); the message is one line."""


@dataclass(frozen=True)
class Band:
    """Frequencies ``freqs_hz`` (ascending) where the speed ``speeds_mm_s`` is strictly monotonic and of sign
    ``sign`` (the zero crossing, if any, included as an end point with speed 0)."""

    index: int
    sign: int  # +1 forward, -1 backward, 0 both (a run through zero speed: where the walker stands, see stand_band)
    freqs_hz: tuple[float, ...]
    speeds_mm_s: tuple[float, ...]

    @property
    def f_lo(self) -> float:
        return self.freqs_hz[0]

    @property
    def f_hi(self) -> float:
        return self.freqs_hz[-1]

    @property
    def v_min(self) -> float:
        return min(self.speeds_mm_s)

    @property
    def v_max(self) -> float:
        return max(self.speeds_mm_s)

    @property
    def span(self) -> float:
        return self.v_max - self.v_min

    def reaches(self, v: float) -> bool:
        return self.v_min - 1e-9 <= v <= self.v_max + 1e-9

    def clip(self, v: float) -> float:
        """``v`` limited to the speeds this band reaches."""
        return min(max(v, self.v_min), self.v_max)

    def frequency_for(self, v: float) -> float:
        """The frequency whose (interpolated) speed is ``v``, ``v`` clipped to the band."""
        s = np.asarray(self.speeds_mm_s)
        f = np.asarray(self.freqs_hz)
        order = np.argsort(s)
        return float(np.interp(self.clip(v), s[order], f[order]))

    def speed_at(self, hz: float) -> float:
        """The map's speed at ``hz`` (interpolated; clipped to the band's frequencies)."""
        return float(np.interp(hz, self.freqs_hz, self.speeds_mm_s))

    def describe(self) -> str:
        return f"{self.f_lo:.1f}-{self.f_hi:.1f} Hz ({self.v_min:+.0f}..{self.v_max:+.0f} mm/s)"


@dataclass(frozen=True)
class SpeedMap:
    """Measured walking speed per drive frequency, with the points flagged irregular; ``source`` says where from."""

    freqs_hz: tuple[float, ...]
    speeds_mm_s: tuple[float, ...]
    irregular: tuple[bool, ...]
    source: str = ""

    @classmethod
    def from_points(
        cls,
        freqs_hz: Sequence[float] | Any,
        speeds_mm_s: Sequence[float] | Any,
        stderr_mm_s: Sequence[float] | Any | None = None,
        regimes: Sequence[str] | None = None,
        source: str = "",
    ) -> SpeedMap:
        """A map from per-frequency measurements (a sweep's analysis): NaN speeds and 0 Hz are dropped,
        duplicate frequencies averaged; irregular points flagged as the module docstring says."""
        f = np.asarray(freqs_hz, float)
        v = np.asarray(speeds_mm_s, float)
        if f.shape != v.shape:
            raise SpeedMapError("the map's frequencies and speeds differ in length")
        se = np.asarray(stderr_mm_s, float) if stderr_mm_s is not None else np.zeros_like(v)
        bad = np.array([("irregular" in str(r).lower()) for r in regimes], bool) if regimes is not None else None
        ok = np.isfinite(f) & np.isfinite(v) & (f > 0)
        if ok.sum() < 2:
            raise SpeedMapError("the map has fewer than two frequencies with a measured speed")
        se_ok = se[ok & np.isfinite(se)]
        median = float(np.median(se_ok)) if len(se_ok) else 0.0
        noisy = np.isfinite(se) & (se > IRREGULAR_STDERR_FACTOR * median) if median > 0 else np.zeros_like(ok)
        flagged = noisy | (bad if bad is not None else False)
        out_f, out_v, out_i = [], [], []
        for hz in np.unique(f[ok]):
            k = ok & (f == hz)
            out_f.append(float(hz))
            out_v.append(float(v[k].mean()))
            out_i.append(bool(flagged[k].any()))
        return cls(tuple(out_f), tuple(out_v), tuple(out_i), source)

    def speed_at(self, hz: float) -> float:
        """The map's speed at ``hz`` (interpolated; 0 at 0 Hz, the last point's speed above the map)."""
        return float(np.interp(hz, (0.0, *self.freqs_hz), (0.0, *self.speeds_mm_s)))

    def bands(self, max_frequency_hz: float = np.inf) -> list[Band]:
        """Every band (see the module docstring), by ascending frequency."""
        f = np.asarray(self.freqs_hz)
        v = np.asarray(self.speeds_mm_s)
        usable = ~np.asarray(self.irregular) & (f <= max_frequency_hz)
        runs: list[list[int]] = []
        run: list[int] = []
        for i in range(len(f)):
            if not usable[i]:
                run = _close(runs, run)
                continue
            if run and v[i] == v[run[-1]]:  # flat: not strictly monotonic
                run = _close(runs, run)
            elif len(run) >= 2 and np.sign(v[i] - v[run[-1]]) != np.sign(v[run[-1]] - v[run[-2]]):
                last = run[-1]
                run = [*_close(runs, run), last]  # the turning point also starts the next run
            run.append(i)
        _close(runs, run)
        bands: list[Band] = []
        for r in runs:
            if np.sign(v[r]).min() < 0 < np.sign(v[r]).max() and np.ptp(v[r]) >= MIN_BAND_SPAN_MM_S:  # to stand in
                bands.append(Band(0, 0, tuple(float(x) for x in f[r]), tuple(float(x) for x in v[r])))
            for sign in (1, -1):
                pts = _signed_part(f[r], v[r], sign)
                if pts is not None and max(pts[1]) - min(pts[1]) >= MIN_BAND_SPAN_MM_S:
                    bands.append(Band(0, sign, pts[0], pts[1]))
        bands.sort(key=lambda b: (b.f_lo, b.sign))
        return [Band(i, b.sign, b.freqs_hz, b.speeds_mm_s) for i, b in enumerate(bands)]

    def reach(self, max_frequency_hz: float = np.inf) -> tuple[float, float]:
        """(fastest backward speed ≤ 0, fastest forward speed ≥ 0) any band reaches (mm/s)."""
        bands = self.bands(max_frequency_hz)
        back = min((b.v_min for b in bands if b.sign < 0), default=0.0)
        fwd = max((b.v_max for b in bands if b.sign > 0), default=0.0)
        return back, fwd

    def stand_band(self, current: Band | None, max_frequency_hz: float = np.inf) -> Band | None:
        """Where to stand (speed 0) coming from ``current``: the run through zero speed that holds ``current``'s
        zero edge (None: no such run, or standing from rest: then 0 Hz)."""
        if current is None or current.sign == 0:
            return current
        edge = current.f_lo if current.speeds_mm_s[0] == 0 else current.f_hi
        runs = [b for b in self.bands(max_frequency_hz) if b.sign == 0 and b.f_lo <= edge <= b.f_hi]
        return runs[0] if runs else None

    def band_for(self, v: float, max_frequency_hz: float = np.inf, current: Band | None = None) -> Band | None:
        """The band to reach ``v`` in: the current one if it still does (same direction), else the one with the
        widest speed span, then the widest frequency span; None for ``v`` = 0 or out of reach."""
        if v == 0:
            return None
        sign = 1 if v > 0 else -1
        if current is not None and current.sign == sign and current.reaches(v):
            return current
        found = [b for b in self.bands(max_frequency_hz) if b.sign == sign and b.reaches(v)]
        if not found:
            return None
        return max(found, key=lambda b: (round(b.span, 6), b.f_hi - b.f_lo))

    def check_targets(self, targets_mm_s: Sequence[float], max_frequency_hz: float = np.inf) -> tuple[int, str] | None:
        """None if every target is reachable, else (the first target out of reach, one line naming the reach per
        direction)."""
        back, fwd = self.reach(max_frequency_hz)
        limit = f" up to {max_frequency_hz:g} Hz" if np.isfinite(max_frequency_hz) else ""
        for i, v in enumerate(targets_mm_s):
            if v != 0 and self.band_for(v, max_frequency_hz) is None:
                if (back, fwd) == (0.0, 0.0):
                    return i, f"the speed map has no usable band{limit}"
                return (
                    i,
                    f"out of reach of the speed map{limit}: forward 0..{fwd:+.1f} mm/s, backward {back:+.1f}..0 mm/s",
                )
        return None


def _close(runs: list[list[int]], run: list[int]) -> list[int]:
    """Append ``run`` to ``runs`` if it has two points or more; returns a fresh run."""
    if len(run) >= 2:
        runs.append(list(run))
    return []


def _signed_part(f: np.ndarray, v: np.ndarray, sign: int) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """The part of a monotonic run where the speed has ``sign``, with the zero crossing as an end point."""
    keep = np.sign(v) == sign
    if not keep.any():
        return None
    idx = np.flatnonzero(keep)  # contiguous: the run is monotonic
    lo, hi = int(idx[0]), int(idx[-1])
    ff, vv = list(f[lo : hi + 1]), list(v[lo : hi + 1])
    if lo > 0:  # the crossing between lo-1 and lo
        ff.insert(0, _crossing(f[lo - 1], v[lo - 1], f[lo], v[lo]))
        vv.insert(0, 0.0)
    if hi < len(f) - 1:
        ff.append(_crossing(f[hi], v[hi], f[hi + 1], v[hi + 1]))
        vv.append(0.0)
    if len(ff) < 2:
        return None
    return tuple(float(x) for x in ff), tuple(float(x) for x in vv)


def _crossing(f0: float, v0: float, f1: float, v1: float) -> float:
    return float(f0 if v1 == v0 else f0 + (f1 - f0) * (0 - v0) / (v1 - v0))
