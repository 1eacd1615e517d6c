"""On a prior set with physical bounds (sim_backend/rod_physical.yaml's ``bounds:``) the calibrator's
unknowns are searched inside those ranges — every corner of the box is a physically possible rig — and the
documented effective sets (no bounds) keep the generic boxes."""

from __future__ import annotations

import itertools

import pytest

from beambench.sim.models.params import load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.scene_params import RigParams
from beambench.sim.scenes.contact_regimes import static_sag
from beambench.sim.settings import SimSettings
from beambench.studies.twin_calibration import get_rig
from beambench.studies.twin_calibration.contact import calibrated_params, contact_boxes, physical_gap
from beambench.studies.twin_calibration.rig import CalibrationBase
from beambench.studies.twin_calibration.search import free_unknowns
from beambench.studies.twin_calibration.walker import walker_boxes

PHYSICAL = CalibrationBase("rod5g", "physical", SimSettings(twist_deg=90.0))
CORNER_UNKNOWNS = ("k_scale", "b_scale", "friction_scale", "frame_mass_g", "mass_dx_mm", "mass_dy_mm")


def test_every_corner_of_the_contact_box_is_a_physical_rig():
    """The search box of every contact unknown on the physical prior: applied at each corner (32 corners of
    stiffness, damping, friction, frame mass and the load offsets), the parameter set has nothing outside its bounds; the preload
    box gives h' at its physical ends at the prior's own sag."""
    boxes = contact_boxes(PHYSICAL)
    assert set(boxes) == {"preload_mm", *CORNER_UNKNOWNS}
    prior = load_params("physical", model="rod")
    sag = static_sag(make_beam_model("rod5g", prior), RigParams.with_overrides(prior.rig), 90.0)
    gap = prior.bounds["rig.plate_gap"]
    assert boxes["preload_mm"] == pytest.approx((1e3 * (sag - gap.max), 1e3 * (sag - gap.min)))
    e = prior.bounds["beam.material.youngs_modulus"]
    assert boxes["k_scale"] == pytest.approx(
        (e.min / prior.material.youngs_modulus, e.max / prior.material.youngs_modulus)
    )
    beta = prior.bounds["beam.beta"]
    assert boxes["b_scale"] == pytest.approx((beta.min / prior.beta, beta.max / prior.beta))
    for corner in itertools.product(*(boxes[n] for n in CORNER_UNKNOWNS)):
        params = calibrated_params(PHYSICAL, dict(zip(CORNER_UNKNOWNS, corner)))
        assert params.out_of_bounds() == [], (corner, params.out_of_bounds())
    # the rig's generic boxes would have left the physical ranges: the damping scale up to 4 (beta 35 ms),
    # the frame up to 15 g; and the preload -0.3..1 mm is not h' 4.5-6.5 mm at this sag
    generic = {u.name: (u.lo, u.hi) for u in get_rig("contact").unknowns}
    assert generic["b_scale"][1] > boxes["b_scale"][1] and generic["frame_mass_g"][1] > boxes["frame_mass_g"][1]
    lo, hi = generic["preload_mm"]
    assert (lo, hi) != pytest.approx(boxes["preload_mm"], abs=0.05)  # not the physical h' range at this sag


def test_the_stiffness_scale_moves_a_rods_modulus_and_so_its_sag():
    """k_scale on a rod (whose springs come from E, not from k) scales E, so the beam sags less in proportion;
    the material's loss time constant beta stays (its hinges' damping b = beta·k scales with E: every corner of
    the k and b boxes is then inside beta's bounds); on a PRB3 set it scales k as before. (It used to scale only
    k, which a rod does not read, and divide beta: a damping change under the stiffness's name.)"""
    prior = load_params("physical", model="rod")
    stiff = calibrated_params(PHYSICAL, {"k_scale": 1.2})
    assert stiff.material.youngs_modulus == pytest.approx(1.2 * prior.material.youngs_modulus)
    assert stiff.beta == pytest.approx(prior.beta)
    rig = RigParams.with_overrides(prior.rig)
    sag = [static_sag(make_beam_model("rod5g", p), rig, 90.0) for p in (prior, stiff)]
    assert sag[1] < sag[0]
    assert sag[1] == pytest.approx(sag[0] / 1.2, rel=0.08)  # linear beam, the frame's lever: sag ~ 1/E
    paper = CalibrationBase("prb3", "contact_paper")
    assert calibrated_params(paper, {"k_scale": 2.0}).k == pytest.approx(2.0 * load_params("contact_paper").k)


def test_the_search_uses_the_physical_boxes_and_keeps_the_gap_inside_h_prime():
    rig = get_rig("contact")
    free, _ = free_unknowns(rig, rig_settings(), contact_boxes(PHYSICAL))
    boxes = contact_boxes(PHYSICAL)
    for u in free:
        assert (u.lo, u.hi) == pytest.approx(boxes[u.name]), u.name
    prior = load_params("physical", model="rod")
    assert physical_gap(prior, 0.0080) == pytest.approx(0.0065)
    assert physical_gap(prior, 0.0030) == pytest.approx(0.0045)
    assert physical_gap(prior, 0.0055) == pytest.approx(0.0055)
    stuck = load_params("contact_stuck")  # an effective set: no bounds, no boxes, the gap as computed
    assert physical_gap(stuck, 0.0092) == pytest.approx(0.0092)
    assert contact_boxes(CalibrationBase("prb3", "contact_stuck")) == {}


def test_the_walker_searches_its_physical_foot_friction_and_radius_ranges():
    physical = load_params("physical", model="rod")
    assert walker_boxes(PHYSICAL) == {
        name: (physical.bounds[f"walker.{name}"].min, physical.bounds[f"walker.{name}"].max)
        for name in ("foot_mass", "friction", "eccentric_radius")
    }
    assert walker_boxes(CalibrationBase("prb3", "paper")) == {}


def rig_settings():
    from beambench.studies.twin_calibration.evaluate import SearchSettings

    return SearchSettings(free=("b_scale", "preload_mm", "friction_scale", "frame_mass_g", "mass_dx_mm"))
