"""Unknowns (studies/unknowns.py): physical bounds the search cannot leave, and one way a value goes into a parameter
set — shared by the calibration, the release fit and the sweep."""

from __future__ import annotations

import math

import pytest

from beambench.sim.models.params import load_params
from beambench.studies.fit.space import ParamSpace
from beambench.studies.twin_calibration import SearchSettings, get_rig
from beambench.studies.twin_calibration.contact import CONTACT_UNKNOWNS, calibrated_params
from beambench.studies.twin_calibration.rig import CalibrationBase
from beambench.studies.twin_calibration.search import free_unknowns
from beambench.studies.twin_calibration.targets import CalibrationInputError
from beambench.studies.unknowns import BEAM_OVERRIDES, Override, Unknown, apply_values


def test_bounds_are_a_finite_interval_and_a_search_box_only_narrows_them():
    with pytest.raises(ValueError, match="not a finite interval"):
        Unknown("x", 1.0, 1.0)
    with pytest.raises(ValueError, match="lo > 0"):
        Unknown("x", 0.0, 2.0, log=True)
    with pytest.raises(ValueError, match="default 3 outside"):
        Unknown("x", 0.0, 2.0, default=3.0)
    u = Unknown("x", 0.1, 10.0, log=True)
    assert u.bounds == (-1.0, 1.0) and u.value(0.5) == pytest.approx(math.sqrt(10.0))
    assert u.within(0.2, 5.0).bounds == pytest.approx((math.log10(0.2), math.log10(5.0)))
    with pytest.raises(ValueError, match="not inside its bounds"):
        u.within(0.01, 5.0)
    # the calibrator refuses a box beyond an unknown's bounds (one line), and an unknown it does not know
    rig = get_rig("contact")
    with pytest.raises(CalibrationInputError, match="bounds: preload_mm"):
        free_unknowns(rig, SearchSettings(bounds={"preload_mm": (-1.0, 0.5)}))
    with pytest.raises(CalibrationInputError, match="unknown 'gravity'"):
        free_unknowns(rig, SearchSettings(bounds={"gravity": (0.0, 1.0)}))
    with pytest.raises(CalibrationInputError, match="fixed: k_scale = 3 is outside its bounds"):
        free_unknowns(rig, SearchSettings(fixed={"k_scale": 3.0}))
    free, _ = free_unknowns(rig, SearchSettings(bounds={"preload_mm": (0.0, 0.5)}))
    assert [u.name for u in free] == ["b_scale", "preload_mm", "friction_scale"]
    assert free[1].bounds == (0.0, 0.5)


def test_overrides_set_and_scale_fields_nested_and_in_the_rig_block():
    p = load_params("contact_paper")
    q = Override(("k", "k_twist"), scale=True, inverse=("beta",))(p, 0.5)
    assert (q.k, q.k_twist, q.beta) == (p.k * 0.5, p.k_twist * 0.5, p.beta / 0.5)
    q = Override(("material.youngs_modulus",))(p, 3e7)
    assert q.material.youngs_modulus == 3e7 and p.material.youngs_modulus != 3e7
    q = Override(("rig.frame_mass",), si=1e-3)(p, 4.0)
    assert q.rig["frame_mass"] == pytest.approx(0.004) and "frame_mass" not in p.rig
    with pytest.raises(ValueError, match="no sole_damping to scale"):
        Override(("rig.sole_damping",), scale=True)(p, 2.0)
    assert Unknown("preload_mm", -1.0, 1.0).apply(p, 0.3) is p  # no effect on the parameter set


def test_the_fit_the_sweep_and_the_calibration_apply_values_the_same_way():
    base = load_params("paper")
    # the fit's PRB3 space: k and b on the bending and twist joints alike, lengths as given
    space = ParamSpace.prb3(base)
    x = [math.log10(0.5), math.log10(0.004), 0.02]
    fitted = space.params(x)
    v = space.values(x)
    direct = apply_values(base, [Unknown(k, -1e9, 1e9, effect=BEAM_OVERRIDES[k]) for k in v], v)
    assert (fitted.k, fitted.k_twist, fitted.b, fitted.b_twist, fitted.l2) == (
        direct.k,
        direct.k_twist,
        direct.b,
        direct.b_twist,
        direct.l2,
    )
    assert fitted.k_twist == pytest.approx(0.5) and fitted.b_twist == pytest.approx(0.004)
    # the contact rig's scales: k_scale scales k and the Young's modulus (a rod's springs), b_scale the damping;
    # a rod's loss time constant beta moves with b_scale only
    assert [u.name for u in CONTACT_UNKNOWNS][:2] == ["b_scale", "k_scale"]
    p = calibrated_params(CalibrationBase("prb3", "paper"), {"k_scale": 0.5, "b_scale": 2.0})
    assert (p.k, p.b_twist, p.beta) == (base.k * 0.5, base.b_twist * 2.0, base.beta * 2.0)
    assert p.material.youngs_modulus == base.material.youngs_modulus * 0.5
