"""A point of the contact twin's physical box (:func:`beambench.sim.scenes.contact_screen.point_twin`, the one the
box search, the one-at-a-time bounds study and the flight study all run): bounds keys land where the set keeps
them, and the contact's damping ratio moves at a fixed stiffness."""

from __future__ import annotations

import pytest

from beambench.sim.models.params import load_params
from beambench.sim.scenes.contact_screen import converged_dt, point_twin


def test_bounds_keys_land_in_the_beam_its_material_and_the_rig():
    twin = point_twin({"beam.beta": 2e-3, "beam.material.youngs_modulus": 60e6, "rig.friction": 0.7, "damping": 1.0})
    _, rig = twin.build()
    assert twin.params.beta == 2e-3 and twin.params.material.youngs_modulus == 60e6
    assert rig.friction == 0.7
    shipped = load_params("physical", "rod")
    assert twin.params.material.poisson == shipped.material.poisson  # untouched numbers stay the set's
    assert rig.contact_timeconst == shipped.rig["contact_timeconst"]  # no ζ given: the time constant as shipped


@pytest.mark.parametrize("zeta", [0.15, 0.5, 1.0])
@pytest.mark.parametrize("tc", [None, 5e-4, 2e-3])
def test_the_damping_ratio_moves_at_a_fixed_stiffness(tc, zeta):
    """MuJoCo's contact stiffness goes with 1/(tc·ζ)²: with ζ given, tc·ζ is the given (or shipped) time constant,
    so the stiffness and the timestep that resolves it stay; only the damping moves."""
    values = {"rig.contact_dampratio": zeta} | ({} if tc is None else {"rig.contact_timeconst": tc})
    _, rig = point_twin(values).build()
    stiff = load_params("physical", "rod").rig["contact_timeconst"] if tc is None else tc
    assert rig.contact_dampratio == zeta
    assert rig.contact_timeconst * rig.contact_dampratio == pytest.approx(stiff, rel=1e-12)
    _, at_one = point_twin({k: v for k, v in values.items() if k != "rig.contact_dampratio"}).build()
    assert converged_dt(rig) == converged_dt(at_one)  # the same stiffness needs the same step
