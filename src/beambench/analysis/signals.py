"""Small signal helpers: sinusoid fit (drive frequency and amplitude), derivatives on uneven samples."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SineFit:
    """``x(t) ≈ offset + amplitude·sin(2π·frequency·t + phase)``; ``rms`` is the residual RMS."""

    frequency_hz: float
    amplitude: float
    phase: float
    offset: float
    rms: float
    n: int

    def __call__(self, t: np.ndarray) -> np.ndarray:
        return self.offset + self.amplitude * np.sin(2 * np.pi * self.frequency_hz * np.asarray(t) + self.phase)


NAN_SINE = SineFit(float("nan"), float("nan"), float("nan"), float("nan"), float("nan"), 0)


def _linear_sine(t: np.ndarray, x: np.ndarray, f: float) -> tuple[np.ndarray, float]:
    """Least-squares (cos, sin, 1) coefficients at a fixed frequency and the residual sum of squares."""
    w = 2 * np.pi * f * t
    a = np.column_stack([np.cos(w), np.sin(w), np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(a, x, rcond=None)
    r = x - a @ coef
    return coef, float(r @ r)


def fit_sinusoid(t_s: np.ndarray, x: np.ndarray, f_guess: float | None = None, *, band: float = 0.25) -> SineFit:
    """Fit one sinusoid to unevenly sampled ``x(t)`` with gaps (NaN allowed).

    Frequency: peak of a Hann-windowed, zero-padded spectrum of the data interpolated onto a uniform grid
    (searched within ±``band``·f_guess, at least ±1 Hz, when ``f_guess`` is given), refined by nonlinear
    least squares on the original samples. Returns :data:`NAN_SINE` when there are too few samples.
    """
    t = np.asarray(t_s, np.float64)
    x = np.asarray(x, np.float64)
    ok = np.isfinite(t) & np.isfinite(x)
    t, x = t[ok], x[ok]
    if len(t) < 8 or np.ptp(t) <= 0:
        return NAN_SINE
    t0 = t[0]
    tt = t - t0
    dt = float(np.median(np.diff(tt)))
    if dt <= 0:
        return NAN_SINE
    grid = np.arange(0.0, tt[-1], dt)
    xu = np.interp(grid, tt, x)
    xu = (xu - xu.mean()) * np.hanning(len(xu))
    nfft = 1 << int(np.ceil(np.log2(max(len(xu), 16) * 8)))
    spec = np.abs(np.fft.rfft(xu, nfft))
    freqs = np.fft.rfftfreq(nfft, dt)
    sel = freqs > 0.5 / max(tt[-1], dt)
    if f_guess is not None and np.isfinite(f_guess) and f_guess > 0:
        half = max(band * f_guess, 1.0)
        sel &= np.abs(freqs - f_guess) <= half
    if not sel.any():
        return NAN_SINE
    idx = np.flatnonzero(sel)
    k = idx[np.argmax(spec[idx])]
    f0 = float(freqs[k])
    if 0 < k < len(spec) - 1:  # parabolic peak interpolation
        y0, y1, y2 = np.log(spec[k - 1 : k + 2] + 1e-300)
        den = y0 - 2 * y1 + y2
        if den < 0:
            f0 += 0.5 * (y0 - y2) / den * (freqs[1] - freqs[0])
    # nonlinear least squares with the linear parameters profiled out: minimise RSS(f) near the peak
    df = float(freqs[1] - freqs[0])
    from scipy.optimize import minimize_scalar

    best = minimize_scalar(
        lambda fr: _linear_sine(tt, x, fr)[1],
        bounds=(f0 - df, f0 + df),
        method="bounded",
        options={"xatol": 1e-7 * max(f0, 1.0)},
    )
    f, rss = float(best.x), float(best.fun)
    (c, s, off), _ = _linear_sine(tt, x, f)
    amp = float(np.hypot(c, s))
    # c·cos + s·sin = amp·sin(w + phase) with sin(phase) = c/amp, cos(phase) = s/amp; shift to t = 0.
    phase = float(np.arctan2(c, s) - 2 * np.pi * f * t0)
    rms = float(np.sqrt(rss / len(tt)))
    return SineFit(float(f), amp, float(np.angle(np.exp(1j * phase))), float(off), rms, len(t))


def velocity(t_s: np.ndarray, x: np.ndarray, smooth_s: float = 0.0) -> np.ndarray:
    """Time derivative of ``x[n, ...]`` on uneven samples (NaN-aware central differences).

    With ``smooth_s`` > 0 the data are first smoothed by a centred moving average of that length.
    """
    t = np.asarray(t_s, np.float64)
    v = np.asarray(x, np.float64)
    if smooth_s > 0 and len(t) > 2:
        dt = float(np.median(np.diff(t)))
        k = max(1, round(float(smooth_s / dt)))
        if k > 1:
            from scipy.ndimage import uniform_filter1d

            v = uniform_filter1d(v, k, axis=0, mode="nearest")
    if len(t) < 2:
        return np.full_like(v, np.nan)
    step = np.concatenate([[True], np.diff(t) > 0])
    if step.all():
        return np.gradient(v, t, axis=0)
    out = np.full_like(v, np.nan)  # repeated time stamps: differentiate the distinct ones, copy to repeats
    idx = np.flatnonzero(step)
    if len(idx) >= 2:
        out[idx] = np.gradient(v[idx], t[idx], axis=0)
        out = out[np.maximum.accumulate(np.where(step, np.arange(len(t)), 0))]
    return out
