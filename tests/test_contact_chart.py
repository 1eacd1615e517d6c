"""The contact chart's pieces: the matched contact's discrete poles, the scene keeping them as the timestep
changes, and a chart point measured against its own finer run."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from beambench.sim.scenes.contact_regimes import ContactTwin
from beambench.sim.scenes.contact_rig import SOLIMP_D0, SOLIMP_DMAX, ContactRigSim, matched_solref
from beambench.studies.contact_chart import ChartPoint, run_point, summarize


def step_map(stiffness: float, damping: float, h: float) -> np.ndarray:
    """MuJoCo's step for the penetration at impedance d0 (direct solref): r'' = −(d/dmax)·b·r' − (d/dmax)²·k·r,
    integrated semi-implicitly (v⁺ = v + h·a, r⁺ = r + h·v⁺); the map of (r, v)."""
    c, w = SOLIMP_D0 / SOLIMP_DMAX * damping, (SOLIMP_D0 / SOLIMP_DMAX) ** 2 * stiffness
    return np.array([[1 - h * h * w, h * (1 - h * c)], [-h * w, 1 - h * c]])


@pytest.mark.parametrize(("tc", "zeta"), [(1e-3, 1.0), (2e-3, 1.0), (1e-3, 0.15), (5e-4, 0.5)])
@pytest.mark.parametrize("h", [5e-5, 2e-4, 4e-4])
def test_the_matched_contact_steps_with_the_continuous_contacts_poles(tc, zeta, h):
    k, b = (-x for x in matched_solref(tc, zeta, h))
    w = SOLIMP_D0 / SOLIMP_DMAX / (tc * zeta)  # the continuous contact's ω at impedance d0
    poles = np.roots([1.0, 2 * zeta * w, w * w])
    exact = np.sort_complex(np.exp(poles * h))
    got = np.sort_complex(np.linalg.eigvals(step_map(k, b, h)).astype(complex))
    np.testing.assert_allclose(got, exact, rtol=1e-6, atol=1e-9)
    # MuJoCo's own (tc, ζ) is the same oscillator stepped without the match: its poles are off, more at a larger h
    plain = np.sort_complex(np.linalg.eigvals(step_map(1 / (tc * zeta) ** 2, 2 / tc, h)).astype(complex))
    assert np.abs(plain - exact).max() > 1e-4 * (h / 5e-5)


def test_the_matched_contact_tends_to_mujocos_own_as_the_step_shrinks():
    k, b = (-x for x in matched_solref(1e-3, 1.0, 1e-8))
    assert k == pytest.approx(1 / 1e-3**2, rel=1e-4) and b == pytest.approx(2 / 1e-3, rel=1e-4)


def test_a_matched_scene_keeps_the_pairs_solref_at_its_timestep():
    bm, rig = ContactTwin("rod3g", "physical", {"contact_matched": True}).build()
    scene = ContactRigSim(bm, 90.0, rig.plate_gap, 0.002, rig)
    pair = scene.physics.model.pair("sole_plate").id
    for h in (2e-4, 5e-5):
        scene.physics.set_timestep(h)
        np.testing.assert_allclose(scene.physics.model.pair_solref[pair], matched_solref(1e-3, 1.0, h))
    snap = scene.snapshot()
    scene.physics.set_timestep(1e-4)
    scene.restore(snap)  # a lookahead undoing a chunk: the timestep and its solref come back together
    np.testing.assert_allclose(scene.physics.model.pair_solref[pair], matched_solref(1e-3, 1.0, 5e-5))
    scene.physics.close()


def test_a_chart_point_is_measured_against_its_own_finer_run():
    rows = []
    for dt in (4e-4, 1e-4):
        rows += run_point(ChartPoint("rod3g", "soft 1 ms", "implicitfast", dt), (30.0, 38.0))
    table = pd.DataFrame(rows)
    assert table["ok"].all() and (table["lift_off_mm"] >= 0).all()
    assert (table["in_contact_fraction"] > 0.3).all()  # the corner touches at both frequencies
    s = summarize(table).set_index("timestep")
    coarse = s.loc[4e-4]
    assert np.isfinite(coarse["own_contact_fraction_err"])  # 4e-4 has its 4× finer run, 1e-4 has none
    assert not np.isfinite(s.loc[1e-4].get("own_contact_fraction_err", np.nan))
    assert coarse["cpu_s_per_sim_s"] < s.loc[1e-4]["cpu_s_per_sim_s"]
