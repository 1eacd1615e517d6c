"""Chirality: φ → −φ mirrors the free beam's tip path across the clamp's y–z plane and reverses its sense."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.sim.scenes.free_beam import FREE_BEAM_SETTINGS, frequency_sweep, orbit_axes, twist_sweep

MIRROR = np.array([-1.0, 1.0, 1.0])  # x → −x: the plane of symmetry of the untwisted beam is y–z


@pytest.mark.parametrize("model", ["prb3", "rod10"])
def test_mirrored_drive_gives_the_exact_mirror_image(model):
    """With the drive mirrored as well (A → −A), the −φ run is the +φ run reflected, sample by sample,
    transient included: the model is built symmetric to rounding error."""
    s = FREE_BEAM_SETTINGS.replace(settle_s=0.0, record_s=0.3, timestep=1e-4)
    plus = frequency_sweep(model, [20.0], s.replace(twist_deg=90.0, amplitude_m=0.002))
    minus = frequency_sweep(model, [20.0], s.replace(twist_deg=-90.0, amplitude_m=-0.002))
    assert np.ptp(plus.tip[0, :, 0]) > 2e-3  # a real motion
    assert np.abs(plus.tip[0] * MIRROR - minus.tip[0]).max() < 1e-9


@pytest.mark.parametrize("model", ["prb3", "rod10"])
def test_opposite_chirality_mirrors_the_orbit_and_reverses_its_sense(model):
    """Same drive for both: in steady state the −φ orbit is the +φ orbit mirrored x → −x (half a period
    later, since the mirrored drive is the drive shifted by T/2), and it is travelled the other way round."""
    f = 20.0
    half = round(0.5 / f / 1e-4)  # T/2 in steps
    s = FREE_BEAM_SETTINGS.replace(settle_s=1.5, record_s=0.1 + 0.5 / f, timestep=1e-4)
    r = twist_sweep(model, twists=[90.0, -90.0], frequency=f, settings=s)
    plus, minus = r.tip[0], r.tip[1]
    n = len(plus) - half
    size = np.ptp(plus[:, 0])
    assert size > 2e-3
    # equal to what is left of the start-up transient (half a period apart: ~1e-4 of the orbit)
    assert np.abs(plus[half : half + n] * MIRROR - minus[:n]).max() < 1e-3 * size
    period = round(1 / f / 1e-4)
    *_, a_plus = orbit_axes(plus[:period])
    *_, a_minus = orbit_axes(minus[:period])
    assert abs(a_plus) > 1e-8  # an open orbit, not a line
    assert a_minus == pytest.approx(-a_plus, rel=0.01)
    major_p, minor_p, tilt_p, _ = orbit_axes(plus[:period])
    major_m, minor_m, tilt_m, _ = orbit_axes(minus[:period])
    assert (major_m, minor_m) == pytest.approx((major_p, minor_p), rel=0.01)
    assert tilt_m == pytest.approx(-tilt_p, abs=0.5)  # the ellipse's tilt flips too
