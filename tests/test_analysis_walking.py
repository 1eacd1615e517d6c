"""Walker body speed from the body marker."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.analysis.walking import body_speed


def test_body_backwards_at_35_mm_s_through_vibration_noise_and_dropouts():
    rng = np.random.default_rng(2)
    t = np.arange(0, 5, 1 / 360)
    x = 0.1 - 0.035 * t + 0.4e-3 * np.sin(2 * np.pi * 23 * t) + rng.normal(0, 1e-4, len(t))  # m
    body = np.stack([x, 0.01 * np.ones_like(t), 0.03 + 0.3e-3 * np.cos(2 * np.pi * 23 * t)], 1)
    body[rng.random(len(t)) < 0.1] = np.nan
    body[700:900] = np.nan
    sp = body_speed(t, body, "x")
    assert sp.speed_mm_s == pytest.approx(-35.0, abs=0.3)
    assert sp.stderr_mm_s < 0.3
    assert sp.distance_mm == pytest.approx(-175.0, rel=0.01)
    # the same motion seen with the forward axis flipped
    assert body_speed(t, body, "-x").speed_mm_s == pytest.approx(35.0, abs=0.3)


def test_body_standing_still_and_too_few_samples():
    t = np.arange(0, 2, 1 / 360)
    body = np.zeros((len(t), 3))
    assert body_speed(t, body).speed_mm_s == pytest.approx(0.0, abs=1e-9)
    assert np.isnan(body_speed(t[:2], body[:2]).speed_mm_s)


def test_speed_curve_shape_finds_the_reversal_and_the_peak():
    """A curve backward below 27 Hz (linear through zero at 27.4) and forward with a parabolic peak at 61.3 Hz,
    sampled every 2 Hz with stand-still jitter (|v| < 5 mm/s) at 1-9 Hz: the reversal is the linear crossing, the
    peak the parabola's vertex, and the jitter is not a reversal."""
    from beambench.analysis.walking import speed_curve_shape

    f = np.arange(1.0, 81.0, 2.0)
    v = np.where(f < 40, 4.0 * (f - 27.4), 150.0 - 0.2 * (f - 61.3) ** 2)
    v[f < 10] = np.array([3.0, -2.0, 4.0, -4.5, 1.0])  # jitter within the dead band
    shape = speed_curve_shape(f[::-1], v[::-1])  # any order
    assert shape.reverses_at_hz == pytest.approx(27.4, abs=1e-9)
    assert shape.peak_at_hz == pytest.approx(61.3, abs=1e-6)
    # never forward: no reversal, no peak; forward only: a peak, no reversal
    none = speed_curve_shape(f, -np.abs(v) - 6.0)
    assert none.reverses_at_hz is None and none.peak_at_hz is None
    fwd = speed_curve_shape(f, np.abs(v) + 6.0)
    assert fwd.reverses_at_hz is None and fwd.peak_at_hz is not None
    # a dip inside the dead band between backward and forward points: the crossing spans it
    shape = speed_curve_shape(np.array([10.0, 12.0, 14.0]), np.array([-10.0, 2.0, 10.0]))
    assert shape.reverses_at_hz == pytest.approx(12.0)
