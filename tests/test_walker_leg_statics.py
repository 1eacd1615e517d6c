"""Can strip legs carry the walker? Statics of the physical twin's walker against hand calculations.

The physical set's legs are the contact rig's 20 × 3 × 50 mm TPU strip (sim_backend/rod_physical.yaml). Two hand
results decide whether the walker stands:

- the load split between the soles and the cart's wheels is a moment balance about the wheel line;
- a sole pushed up by the floor a foot length ``l`` below a sideways leg's tip is an inverted pendulum on the
  strip's torsion: it stands only while ``F · l < GJ / L`` (a rigid foot on a torsion spring ``GJ/L``).

A leg hanging straight down (``leg_droop_deg = 90``) carries its sole load along the strip instead.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from beambench.sim.models.beam import BeamModel
from beambench.sim.models.params import load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.models.rod import RodParams
from beambench.sim.scene_params import WalkerParams
from beambench.sim.scenes.walker import WalkerSim, sole_load

ROOT = Path(__file__).resolve().parents[1]
PHYSICAL = load_params("physical", model="rod")
BEAM = make_beam_model("rod5g", PHYSICAL)
# the strip as soft as the twin's beam was before it was anchored to the release test (14 MPa)
SOFT = replace(PHYSICAL, material=replace(PHYSICAL.material, youngs_modulus=14e6))
G = 9.81


# the contact rig's foot (66.5 mm, its 20 g load) on sideways legs clamped width-vertical, unraked: the walker these
# statics are about (the shipped walker's own short feet: tests/test_walker_twin.py)
FOLDING = {"foot_length": 0.0665, "foot_mass": 0.020, "leg_mount_deg": 0.0, "leg_roll_deg": 0.0, "spin": -1.0}


def _walker(beam: BeamModel = BEAM, **overrides: float) -> WalkerSim:
    return WalkerSim(beam, 90.0, WalkerParams.with_overrides({**PHYSICAL.walker, **FOLDING, **overrides}))


def folding_protocol(tmp_path: Path) -> Path:
    """A one-step walker protocol on a 14 MPa strip under the contact rig's foot (legs that fold), its parameters a
    copy of the physical set's file."""
    soft = yaml.safe_load((ROOT / "sim_backend" / "rod_physical.yaml").read_text())
    soft["beam"]["material"]["youngs_modulus"] = 14e6
    soft["walker"].update(FOLDING)
    soft_path = tmp_path / "rod_soft.yaml"
    soft_path.write_text(yaml.safe_dump(soft))
    proto = tmp_path / "w.yaml"
    proto.write_text(
        "name: w\nrig: walker\nbackend: sim\nsweep: {frequencies: [10]}\nsettle_s: 0.2\nrecord_s: 0.3\n"
        f"sim: {{model: rod5g, params: {soft_path}, noise: false}}\n"
    )
    return proto


def walker_normal_forces(sim: WalkerSim) -> dict[str, float]:
    """The floor's normal force (N) on the soles and on the wheels, summed over their contacts (contact frame x =
    the floor's normal)."""
    m, d = sim.physics.model, sim.physics.data
    mujoco.mj_forward(m, d)
    out = {"sole": 0.0, "wheel": 0.0}
    f6 = np.zeros(6)
    for i in range(d.ncon):
        c = d.contact[i]
        mujoco.mj_contactForce(m, d, i, f6)
        name = m.geom(c.geom2 if m.geom(c.geom1).name == "floor" else c.geom1).name
        out[name.split("_")[0]] += float(f6[0])
    return out


@pytest.mark.parametrize("motor_x", [0.0, -0.12])
def test_hanging_legs_stand_and_share_the_weight_by_the_moment_balance(motor_x):
    """Legs hanging down stand (the body stays at its clamp height within 1 mm for 1 s, motor off), the contacts
    carry the whole weight, and the soles' share is the moment balance's within 3 %; moving the motor toward the
    cart moves weight onto the wheels."""
    sim = _walker(leg_droop_deg=90.0, foot_length=0.010, motor_x=motor_x)
    try:
        z_nominal = PHYSICAL.length + 0.010
        body = sim.advance_to(1.0).channels["markers"][:, 0, 2]
        assert np.abs(body - z_nominal).max() < 1e-3, (body.min(), body.max(), z_nominal)
        forces = walker_normal_forces(sim)
        weight = float(sim.physics.model.body_subtreemass[sim.physics.model.body("walker").id]) * G
        assert forces["sole"] + forces["wheel"] == pytest.approx(weight, rel=0.02)
        share = 2.0 * sole_load(sim.physics.model) / weight  # the moment balance about the wheels
        assert forces["sole"] / weight == pytest.approx(share, abs=0.03)
        if motor_x < 0:
            assert share < 0.6  # the motor and offset mass (150 g) halfway to the cart: the wheels carry more
        else:
            assert share > 0.65
    finally:
        sim.physics.close()


def test_the_anchored_strip_legs_carry_the_walker_below_their_torsional_limit():
    """The physical legs (the beam anchored to the release test) under the contact rig's 66.5 mm foot: each sole
    carries less than the torsional limit GJ_twisted/(L·l) of the pre-twisted strip, though more than Saint-Venant's
    GJ alone would hold (the trapeze term is what carries it), and the body stays above half its clamp height for
    1 s, motor off."""
    rod = RodParams.from_beam(PHYSICAL)
    sim = _walker()
    try:
        wp = sim.rig
        per_sole = sole_load(sim.physics.model)
        limit = rod.torsion_gj(PHYSICAL.twist_deg) / (rod.length * wp.foot_length)
        assert per_sole < limit < per_sole * rod.torsion_gj(PHYSICAL.twist_deg) / rod.gj, (per_sole, limit)
        assert per_sole > rod.gj / (rod.length * wp.foot_length)
        body = sim.advance_to(1.0).channels["markers"][:, 0, 2]
        clamp = wp.foot_length + 0.002
        assert body.min() > clamp / 2, (body.min(), clamp)
    finally:
        sim.physics.close()


def test_a_softer_strip_folds_in_torsion_under_the_walkers_weight():
    """The same walker on a 14 MPa strip: each sole carries > 1.5x the torsional limit and the body falls through
    the floor (no body collision) within 1 s: the legs fold."""
    rod = RodParams.from_beam(SOFT)
    sim = _walker(make_beam_model("rod5g", SOFT))
    try:
        wp = sim.rig
        per_sole = sole_load(sim.physics.model)
        limit = rod.torsion_gj(SOFT.twist_deg) / (rod.length * wp.foot_length)
        assert 1.5 < per_sole / limit < 10.0, (per_sole, limit)
        body = sim.advance_to(1.0).channels["markers"][:, 0, 2]
        clamp = wp.foot_length + 0.002
        assert body[-1] < clamp - wp.foot_length, (body[-1], clamp)  # below the floor: the feet folded under
    finally:
        sim.physics.close()


def test_a_light_body_on_sideways_legs_stands_below_the_torsional_limit():
    """The same legs and foot under a body light enough that F·l < GJ/L (motor, offset mass and plate nearly
    massless, cart as shipped): the legs hold, the body sinks only by the strip's bending sag (< 5 mm)."""
    rod = RodParams.from_beam(PHYSICAL)
    sim = _walker(motor_mass=0.002, eccentric_mass=0.001, plate_mass=0.002, foot_mass=0.002)
    try:
        wp = sim.rig
        per_sole = sole_load(sim.physics.model)
        assert per_sole < 0.6 * rod.gj / (rod.length * wp.foot_length), per_sole  # Saint-Venant alone holds it
        body = sim.advance_to(1.0).channels["markers"][:, 0, 2]
        clamp = wp.foot_length + 0.002
        assert clamp - body[-1] < 5e-3, (clamp, body[-1])
        assert np.abs(np.diff(body[-200:])).max() < 1e-4  # at rest, not falling
    finally:
        sim.physics.close()


def test_the_walker_says_when_its_legs_fold_and_not_otherwise():
    """``leg_fold`` (the run's warning) names a walker on a 14 MPa strip, whose sole load beats
    the torsional limit; not the anchored strip under the same foot (it holds), nor the PRB3 walker, nor legs
    hanging down. Its sole load is the standing PRB3 walker's measured contact force per sole within 3 %."""
    from beambench.sim.scenes.walker import leg_fold

    sim = _walker(make_beam_model("rod5g", SOFT))
    try:
        assert sim.model_warnings() and "legs fold" in sim.model_warnings()[0]
    finally:
        sim.physics.close()
    shipped = _walker()
    try:
        assert shipped.model_warnings() == []
    finally:
        shipped.physics.close()
    hanging = _walker(leg_droop_deg=90.0, foot_length=0.010)
    try:
        assert hanging.model_warnings() == []
    finally:
        hanging.physics.close()
    prb3 = WalkerSim(make_beam_model("prb3", load_params()), 90.0)
    try:
        assert leg_fold(prb3.physics.model, prb3.beam, prb3.rig) is None
        measured = 0.5 * walker_normal_forces(prb3)["sole"]
        assert sole_load(prb3.physics.model) == pytest.approx(measured, rel=0.03)
    finally:
        prb3.physics.close()


def test_a_run_of_a_folding_walker_ends_with_the_fold_warning(tmp_path):
    """The run's result (stderr) carries the model's warning (a walker on a 14 MPa strip); the session is written
    as usual (exit 0)."""
    from typer.testing import CliRunner

    from beambench.cli import app

    proto = folding_protocol(tmp_path)
    res = CliRunner().invoke(app, ["run", str(proto), "--out", str(tmp_path), "--rerun", "off"])
    assert res.exit_code == 0, res.output
    assert "beambench: warning: the walker's rod5g legs fold" in res.stderr, res.stderr
    session = res.stdout.strip().splitlines()[-1]
    assert session.endswith(".h5") and (tmp_path / session).is_file(), res.stdout


def test_the_fold_warning_is_kept_in_the_session_and_shown_atop_the_report(tmp_path):
    """Every warning the run gave is in ``/general/warnings`` (read back as ``SessionFile.warnings``) and is a banner
    at the top of the report's index.html, before the figures."""
    from typer.testing import CliRunner

    from beambench.cli import app
    from beambench.sinks.session_file.reader import read_session

    proto = folding_protocol(tmp_path)
    res = CliRunner().invoke(app, ["run", str(proto), "--out", str(tmp_path), "--rerun", "off"])
    assert res.exit_code == 0, res.output
    session = tmp_path / res.stdout.strip().splitlines()[-1]
    warnings = read_session(session).warnings
    assert len(warnings) == 1 and "rod5g legs fold" in warnings[0], warnings
    out = tmp_path / "report"
    res = CliRunner().invoke(app, ["analyze", str(session), "--out", str(out), "--figures", "none"])
    assert res.exit_code == 0, res.output
    page = (out / "index.html").read_text()
    banner = page.find("class='warn'")
    assert banner != -1 and "rod5g legs fold" in page[banner : page.find("</p>", banner)], page[:2000]
    assert banner < page.find("<h2>"), "the banner comes before the report's sections"
