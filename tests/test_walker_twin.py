"""The shipped physical walker (sim_backend/rod_physical.yaml's walker block on the anchored rod5g legs): it stands,
walks in the paper's directions at 23 and 65 Hz, and is mirror symmetric (docs/walker-twin.md)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from beambench.sim.models.params import load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.scene_params import WalkerParams
from beambench.sim.scenes.walker import WalkerSim, leg_fold
from beambench.sim.scenes.walker_batch import steady_speeds
from beambench.sim.settings import SimSettings

PHYSICAL = load_params("physical", model="rod")
BEAM = make_beam_model("rod5g", PHYSICAL)
SHIPPED = WalkerParams.with_overrides(PHYSICAL.walker)


def clamp_height(wp: WalkerParams) -> float:
    """The body's height with rigid legs (m): the soles 2 mm above the floor at build time."""
    return wp.foot_length + 0.002


def test_the_shipped_walker_stands_on_its_legs():
    """Motor off, 2 s: the body stays above 60 % of its clamp height throughout (the legs sag by bending and the body
    rocks slowly on the lightly damped strips; they do not fold in torsion, which takes the body to
    the floor within 1 s), and the fold criterion agrees (no warning)."""
    sim = WalkerSim(BEAM, 90.0, SHIPPED)
    try:
        z = sim.advance_to(2.0).channels["markers"][:, 0, 2]
        assert z.min() > 0.6 * clamp_height(SHIPPED), (z.min(), clamp_height(SHIPPED))
        assert leg_fold(sim.physics.model, BEAM, SHIPPED) is None
    finally:
        sim.physics.close()


@pytest.fixture(scope="module")
def shipped_speeds() -> tuple[np.ndarray, np.ndarray]:
    """Steady speed (mm/s) and mean body height (mm) at 23 and 65 Hz (settle 3 s from a settled robot)."""
    return steady_speeds(BEAM, [23.0, 65.0], SHIPPED, settings=SimSettings(settle_s=3.0, record_s=1.5, nthread=1))


def test_the_shipped_walker_walks_backward_at_23_hz_and_forward_at_65_hz_like_the_paper(shipped_speeds):
    """Paper Sec. IV-B: −35.7 mm/s at 23 Hz, +156.3 mm/s at 65 Hz. The twin meets both within 30 % (−34.5 / +130.8
    at the scene's timestep, docs/walker-twin.md), standing (body above half its clamp height) at both."""
    v, z = shipped_speeds
    assert v[0] == pytest.approx(-35.7, rel=0.3), v
    assert v[1] == pytest.approx(156.3, rel=0.3), v
    assert np.all(z > 0.5e3 * clamp_height(SHIPPED)), z


def test_swapping_the_legs_chirality_mirrors_the_sideways_drift():
    """Both legs of one chirality make the robot chiral; its mirror image across the sagittal plane has both legs of
    the other chirality and the same rotor (the offset mass turns in the mirror plane). With the lateral slide free,
    the mirror image drifts sideways by the opposite amount along the same forward path (0.6 s, before round-off
    grows), and the drift is real (not a symmetric robot's zero)."""
    base = replace(SHIPPED, lateral_free=1.0)
    paths = []
    for chir in (-1.0, 1.0):
        sim = WalkerSim(BEAM, 90.0, replace(base, left_chirality=chir, right_chirality=chir))
        try:
            sim.set_frequency(40.0)
            paths.append(sim.advance_to(0.6).channels["markers"][:, 0])
        finally:
            sim.physics.close()
    a, b = paths
    assert np.abs(a[:, 1]).max() > 1e-4  # a chiral robot drifts sideways (m) ...
    assert np.abs(a[:, 1] + b[:, 1]).max() < 1e-6  # ... and its mirror image the other way
    assert np.abs(a[:, [0, 2]] - b[:, [0, 2]]).max() < 1e-6


def test_legs_clamped_flat_sag_and_on_edge_stand():
    """The strip clamped with its width vertical (``leg_roll_deg`` 0) carries the body near its clamp height;
    the same strip clamped flat (90: its weak axis under the clamp's largest moment) lets it sink below three
    quarters of it within 1.5 s, motor off (on the shipped rake and feet; raked 10 deg it reaches the floor)."""
    heights = {}
    for roll in (0.0, 90.0):
        sim = WalkerSim(BEAM, 90.0, replace(SHIPPED, leg_roll_deg=roll))
        try:
            heights[roll] = float(sim.advance_to(1.5).channels["markers"][-1, 0, 2])
        finally:
            sim.physics.close()
    assert heights[0.0] > 0.75 * clamp_height(SHIPPED), heights
    assert heights[90.0] < 0.75 * clamp_height(SHIPPED), heights  # 40 mm against 50 (57 mm clamp height)
