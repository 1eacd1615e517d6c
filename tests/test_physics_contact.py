"""The batched contact sweep: subharmonic contact at a 1 mm gap, no contact at the paper's 5.5 mm, and the
per-frequency timesteps agree with a fine one."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.sim.scenes.contact_sweep import contact_ratio, contact_sweep
from beambench.sim.settings import SimSettings


def test_contacts_per_cycle_fall_from_one_to_a_half_with_frequency():
    """PRB3, 1 mm gap: one landing per drive cycle at 20 Hz, one every other cycle at 35 Hz — the same with a
    coarse (2e-4 s) and a fine (2.5e-5 s) timestep; the stage follows the sine exactly."""
    sim = SimSettings(settle_s=0.8, record_s=0.6)
    coarse = contact_sweep("prb3", [20.0, 35.0], sim.replace(timestep=2e-4), gap_m=0.001)
    fine = contact_sweep("prb3", [20.0, 35.0], sim.replace(timestep=2.5e-5), gap_m=0.001)
    for r in (coarse, fine):
        assert r.ok.all()
        ratio = r.contacts_per_cycle()
        assert ratio[0] == pytest.approx(1.0, abs=0.1)
        assert ratio[1] == pytest.approx(0.5, abs=0.1)
        assert r.normal.max() > 0.1  # newtons: real impacts
    err = np.sqrt(np.mean(np.sum((coarse.foot - fine.foot) ** 2, axis=2), axis=1))
    assert (err < 1e-4).all()  # foot paths within 0.1 mm


def test_paper_gap_prb3_foot_never_touches():
    r = contact_sweep("prb3", [10.0, 30.0], SimSettings(settle_s=0.5, record_s=0.3, timestep=1e-4), gap_m=0.0055)
    assert r.ok.all()
    assert (r.normal == 0).all()
    assert np.isnan(r.contacts_per_cycle()).all()


def test_contact_ratio_counts_only_real_flights():
    t = np.arange(0, 1, 1e-4)
    f = 10.0
    lift = np.sin(2 * np.pi * f * t) > 0.5  # airborne a third of each period
    z = np.where(lift, 1e-4, 0.0)
    normal = np.where(lift, 0.0, 1.0)
    assert contact_ratio(t, normal, z, f) == pytest.approx(1.0, abs=0.05)
    chatter = np.where(lift, 1e-6, 0.0)  # a 1 µm hop is not a flight
    assert contact_ratio(t, normal, chatter, f) == 0.0


def test_balanced_threads_give_the_same_runs_as_one_thread():
    """Mixed per-frequency timesteps split over two worker threads: bit-identical to one thread."""
    freqs, dts = [5.0, 12.0, 20.0, 33.0, 40.0], [2.5e-4, 1e-3 / 3, 2e-4, 1e-3 / 3, 5e-4]
    sim = SimSettings(settle_s=0.2, record_s=0.2, integrator="euler", timestep=tuple(dts))
    one = contact_sweep("prb3", freqs, sim.replace(nthread=1))
    two = contact_sweep("prb3", freqs, sim.replace(nthread=2))
    assert one.ok.all() and np.isfinite(one.foot).all()
    assert np.array_equal(one.foot, two.foot) and np.array_equal(one.normal, two.normal)
    assert all(np.array_equal(a[0], b[0]) for a, b in zip(one.contact, two.contact))


def test_euler_equals_implicitfast_on_the_contact_rig():
    """The scene's only velocity-dependent forces are joint damping, which Euler also treats implicitly: the
    two integrators give the same foot path (so the table may pick the cheaper one)."""
    sim = SimSettings(settle_s=0.3, record_s=0.2, timestep=2.5e-4)
    a = contact_sweep("prb3", [25.0], sim.replace(integrator="euler"))
    b = contact_sweep("prb3", [25.0], sim.replace(integrator="implicitfast"))
    assert np.abs(a.foot - b.foot).max() < 1e-9


def test_table_marks_timesteps_that_soften_the_contact():
    """dt above half the 1 ms contact time constant: MuJoCo's refsafe softens the contact to 2·dt, so the
    peak plate force drops — the table marks such rows solref_clamped and selection never picks them."""
    from beambench.sim import selection as select
    from beambench.studies.contact_table import measure_contact_table

    t = measure_contact_table(
        "prb3",
        frequencies=(20.0,),
        timesteps=(2.5e-4, 1e-3),
        integrators=("euler",),
        settle_s=0.3,
        record_s=0.3,
        timing_repeats=1,
    )
    status = dict(zip(t.timestep, t.status))
    assert status[1e-3] == "solref_clamped" and status[2.5e-4] in ("ok", "wrong_contacts")
    sim = SimSettings(settle_s=0.3, record_s=0.3, integrator="euler")
    stiff = contact_sweep("prb3", [20.0], sim.replace(timestep=2.5e-4))
    soft = contact_sweep("prb3", [20.0], sim.replace(timestep=1e-3))
    assert max(x[0].max() for x in soft.contact) < 0.8 * max(x[0].max() for x in stiff.contact)
    plan = select.plan_sweep("contact", 10.0, [20.0], table=t)  # even a loose tolerance: never the clamped row
    assert plan.timestep(20.0) == 2.5e-4
