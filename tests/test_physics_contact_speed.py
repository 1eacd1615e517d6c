"""The shipped contact twin as `beambench run` computes it fast: its timestep policy against a 4× finer step, and
a sweep cut into parallel segments against the same sweep carried in one piece (above the lift-off band)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from beambench.acquisition.protocol.schema import parse_protocol
from beambench.backends.lookahead import Lookahead, cut_points, script
from beambench.backends.sim import build_scene
from beambench.session.slices import sim_slice
from beambench.sim.engine.stepping import Trajectory
from beambench.sim.scenes.contact_regimes import ContactTwin, stepped_regime_map, steps_agree
from beambench.sim.scenes.contact_rig import ContactRigSim
from beambench.sim.settings import SimSettings

TWIN = ContactTwin("rod5g", "physical")
REFERENCE_DT = 2.5e-5


@pytest.mark.slow
def test_the_shipped_policy_gives_the_labels_and_contact_fractions_of_a_finer_step():
    """Above the lift-off band (13–22 Hz, where a micrometre of gap flips the label at any timestep) the policy's
    timestep gives the 2.5e-5 s run's regime at every step and its in-contact fraction within 0.03."""
    freqs = [24.0, 30.0, 38.0]
    sim = SimSettings(settle_s=1.0, record_s=2.0, integrator="implicitfast")
    bm, rig = TWIN.build()
    shipped = ContactRigSim(bm, 90.0, rig.plate_gap, 0.002, rig)
    policy = {f: shipped.timestep_for(f) for f in freqs}
    shipped.physics.close()
    assert min(policy.values()) > REFERENCE_DT  # the policy runs coarser than the reference
    runs = [stepped_regime_map(freqs, sim.replace(timestep=dt), TWIN) for dt in (policy[30.0], REFERENCE_DT)]
    run, ref = runs
    assert list(run["regime"]) == list(ref["regime"]), (list(run["regime"]), list(ref["regime"]))
    diff = np.abs(run["in_contact_fraction"].to_numpy() - ref["in_contact_fraction"].to_numpy())
    assert diff.max() <= 0.03, diff
    assert (ref["in_contact_fraction"] > 0.3).all()  # the foot touches and lifts at every step: a real comparison


CONTACT = """
name: c
rig: contact
sweep: {frequencies: [28, 30, 32, 34, 36]}
settle_s: 0.5
record_s: 1.0
amplitude_mm: 2.0
limits: {max_frequency_hz: 40, max_current_a: 10}
sim: {model: rod5g, params: physical, noise: false, segments: 2}
"""


@pytest.mark.slow
def test_a_checked_cut_keeps_the_regime_of_every_later_step():
    """The cut's check accepts a cut where the state forgets: every step after the switch gives the regime that
    the sweep carried in one piece gives (same label, in-contact fraction within 0.03)."""
    sim = sim_slice(parse_protocol(CONTACT))
    plan = [(f, [0.5, 1.0]) for f in (28.0, 30.0, 32.0, 34.0, 36.0)]
    calls = script(plan, 0, 500_000_000)
    scene = build_scene(sim)
    look = Lookahead(scene, calls, cut_points(calls, 2, 1.0), [build_scene(sim)], 1.0, None, scene.same_regime)
    rows = []
    for kind, t_ns, hz in calls:
        assert look.expects(kind, t_ns, hz)
        rows.append(look.take(next((r for r in reversed(rows) if r is not None), None)))
    look.stop()
    assert len(look.cut_times_ns) == 1  # the check accepted a cut (36 Hz is far above the lift-off band)
    one = build_scene(sim)
    carried = []
    for kind, t_ns, hz in calls:
        if kind == "cmd":
            one.set_frequency(hz)
        carried.append(None if kind == "cmd" else one.advance_to(t_ns * 1e-9))
    cmds = [i for i, c in enumerate(calls) if c[0] == "cmd"] + [len(calls)]
    cut = calls.index(next(c for c in calls if c[1] == look.cut_times_ns[0] and c[0] == "cmd"))
    later = [(a, b) for a, b in itertools.pairwise(cmds) if a >= cut]
    assert later
    for a, b in later:
        seg = Trajectory.concat([r for r in rows[a:b] if r is not None])
        ref = Trajectory.concat([r for r in carried[a:b] if r is not None])
        assert steps_agree(seg, ref, calls[a][2]), calls[a][2]
        assert not np.array_equal(seg.channels["force_nt"], ref.channels["force_nt"])  # another trajectory
