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
