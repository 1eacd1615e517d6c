"""The shipped contact twin's timestep: its contact forces converge at first order as the timestep halves, and the
twin runs at a timestep where they are within a few per cent of a finer run (the check behind
``RigParams.max_timestep``; the full sweep's check is ``benchmarks/bench_contact_convergence.py``)."""

from __future__ import annotations

import itertools

import pytest

from beambench.sim.models.params import load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.scenes.contact_rig import ContactRigSim

LOADCELL_BOX_S = 1e-3  # the load cells average the force over their 1 ms sample


def _contact(timestep: float | None, hz: float = 30.0) -> tuple[float, float, float]:
    """(fraction of load-cell samples in contact, mean tangential force in contact N, the timestep) over 1 s at
    ``hz`` after 1.5 s (30 Hz: one touchdown per cycle, a regime no 1 µm change of the gap moves), the shipped
    set. Robust quantities: the peak normal force, an extreme over a few impacts, is not (it moves by 10 % between
    2.5e-5 and 1.25e-5 s)."""
    beam = make_beam_model("rod5g", load_params("physical", model="rod"))
    sim = ContactRigSim(beam, 90.0, None, timestep=timestep)
    sim.set_frequency(hz)
    sim.advance_to(1.5)
    h = sim.physics.timestep
    force = sim.advance_to(2.5).channels["force_nt"]
    every = max(1, round(LOADCELL_BOX_S / h))
    box = force[: len(force) // every * every].reshape(-1, every, 2).mean(axis=1)
    touching = box[:, 0] > 0.02
    return float(touching.mean()), float(box[touching, 1].mean()), h


@pytest.fixture(scope="module")
def ladder() -> dict[float, tuple[float, float, float]]:
    return {dt: _contact(dt) for dt in (4e-4, 2e-4, 1e-4, 5e-5, 2.5e-5)}


def test_the_contact_fraction_converges_as_the_timestep_halves(ladder):
    dts = sorted(ladder, reverse=True)
    steps = [abs(ladder[a][0] - ladder[b][0]) for a, b in itertools.pairwise(dts)]
    # each halving moves the answer less than the one before (first order: about half as much)
    assert all(later < 0.75 * earlier for earlier, later in itertools.pairwise(steps)), steps
    assert steps[0] > 0.1  # 4e-4 s is far off: the check can fail


def test_the_shipped_twin_runs_where_its_contact_forces_are_converged(ladder):
    fraction, tangential, h = _contact(None)
    ref_fraction, ref_tangential, _ = ladder[2.5e-5]
    assert h >= 2 * 2.5e-5 - 1e-12  # the reference is at least twice as fine: a real comparison
    assert abs(fraction / ref_fraction - 1) < 0.05, (h, fraction, ref_fraction)
    assert abs(tangential / ref_tangential - 1) < 0.05, (h, tangential, ref_tangential)
