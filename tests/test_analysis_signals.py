"""Sinusoid fit and derivatives on uneven, gappy samples."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.acquisition.forces.contact_events import runs
from beambench.analysis.signals import fit_sinusoid, velocity


@pytest.mark.parametrize("f_true", [1.0, 7.3, 26.0, 44.9])
def test_fit_sinusoid_recovers_frequency_and_amplitude_through_noise_and_gaps(f_true):
    rng = np.random.default_rng(int(f_true * 10))
    t = np.sort(rng.uniform(0, 5, 1800))  # uneven, ~360 Hz
    x = 0.3 + 2.0 * np.sin(2 * np.pi * f_true * t + 0.4) + rng.normal(0, 0.05, len(t))
    x[rng.random(len(t)) < 0.1] = np.nan  # dropouts
    x[500:700] = np.nan  # a long hole
    fit = fit_sinusoid(t, x, f_guess=round(f_true))
    assert fit.frequency_hz == pytest.approx(f_true, abs=2e-3)
    assert fit.amplitude == pytest.approx(2.0, rel=0.01)
    assert fit.offset == pytest.approx(0.3, abs=0.01)
    ok = np.isfinite(x)
    assert np.sqrt(np.mean((fit(t[ok]) - x[ok]) ** 2)) < 0.06  # the phase is right too


def test_fit_sinusoid_without_a_guess_and_with_too_little_data():
    t = np.arange(0, 2, 1 / 360)
    fit = fit_sinusoid(t, np.sin(2 * np.pi * 13.0 * t))
    assert fit.frequency_hz == pytest.approx(13.0, abs=1e-3)
    assert np.isnan(fit_sinusoid(t[:5], t[:5]).frequency_hz)
    assert np.isnan(fit_sinusoid(t, np.full_like(t, np.nan)).amplitude)


def test_velocity_handles_repeated_stamps():
    t = np.array([0.0, 0.1, 0.2, 0.2, 0.3, 0.4])
    x = 5.0 * t
    v = velocity(t, x)
    assert np.all(np.isfinite(v)) and np.allclose(v, 5.0)


def test_runs():
    s, e = runs(np.array([0, 1, 1, 0, 1, 0, 0, 1], bool))
    assert s.tolist() == [1, 4, 7] and e.tolist() == [3, 5, 8]
