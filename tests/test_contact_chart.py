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


def _chart_table() -> pd.DataFrame:
    from beambench.sim.models.params import SIM_BACKEND_DIR

    return pd.read_csv(SIM_BACKEND_DIR / "contact_chart.csv")


def test_the_shipped_default_is_read_from_the_shipped_protocol_and_lies_on_the_charts_front():
    """The chart's data: the shipped contact sweep's point (its model, contact, integrator and timestep, read from
    the protocol and its parameter set) is in the table, within tolerance of its physics' finest run, and no point
    of the same physics within tolerance is cheaper (else the assertion names it)."""
    from beambench.acquisition.protocol.schema import load_protocol
    from beambench.common.resources import shipped_dir
    from beambench.studies.contact_chart import FRACTION_TOLERANCE, front_check, shipped_point

    point = shipped_point()
    protocol, _ = load_protocol(shipped_dir("protocols") / "contact_sweep.yaml")
    assert point.model == protocol.sim.model
    table, beaten_by = front_check(_chart_table(), point)
    assert table["shipped"].sum() == 1
    assert beaten_by == [], f"the shipped default {point} is not on the chart's front: {beaten_by}"
    me = table[table["shipped"]].iloc[0]
    assert me["ref_contact_fraction_err"] <= FRACTION_TOLERANCE
    # the front is not empty of rivals: cheaper points of the same physics exist and are out of tolerance
    cheaper = table[table["cpu_s_per_sim_s"] < me["cpu_s_per_sim_s"] * 0.9]
    assert len(cheaper) > 0 and not cheaper["within"].any()


def test_the_front_check_names_a_cheaper_point_within_tolerance_and_follows_the_protocol(tmp_path):
    from beambench.common.resources import shipped_dir
    from beambench.studies.contact_chart import front_check, shipped_point

    point = shipped_point()
    rows = _chart_table()
    # a matched-contact run at 2× the step made as accurate as the reference: it beats the shipped point
    fine = rows[
        (rows["model"] == point.model)
        & (rows["formulation"] == point.formulation)
        & (rows["integrator"] == point.integrator)
    ]
    ref = fine[fine["timestep"].round(12) == fine["timestep"].round(12).min()].sort_values("frequency_hz")
    rival = rows[
        (rows["model"] == point.model)
        & (rows["formulation"] == "matched 1 ms")
        & (rows["timestep"].round(12) == round(2 * point.timestep, 12))
    ].sort_values("frequency_hz")
    assert len(rival) == len(ref) > 0
    better = rows.copy()
    better.loc[rival.index, "in_contact_fraction"] = ref["in_contact_fraction"].to_numpy()
    _, beaten_by = front_check(better, point)
    assert len(beaten_by) == 1 and beaten_by[0].startswith(f"{point.model} matched 1 ms implicitfast 0.0001 s")
    # a protocol with a coarser fixed timestep ships another point: out of tolerance, and the check says so
    text = (
        (shipped_dir("protocols") / "contact_sweep.yaml")
        .read_text()
        .replace("  twist_deg: 90", "  timestep: 1.0e-4\n  twist_deg: 90")
    )
    coarse = tmp_path / "coarse.yaml"
    coarse.write_text(text)
    other = shipped_point(coarse)
    assert other.timestep == 1e-4
    _, said = front_check(rows, other)
    assert len(said) == 1 and "out of tolerance" in said[0]
