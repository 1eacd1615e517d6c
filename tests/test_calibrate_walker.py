"""The walker in `beambench calibrate sim`: registration, objective, the evaluator, and the written protocol."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from beambench.sim.settings import SimSettings
from beambench.studies.twin_calibration import get_rig
from beambench.studies.twin_calibration.rig import parse_targets

TARGETS = parse_targets({"rig": "walker", "speed_mm_s": {23: -35.7, 65: 156.3}}, "<test>")


def test_walker_is_calibratable_in_foot_mass_friction_and_offset_radius():
    rig = get_rig("walker")
    assert [u.name for u in rig.unknowns] == ["foot_mass", "friction", "eccentric_radius"]
    assert rig.stage_sim is not None
    assert rig.stage_sim("coarse", SimSettings()).settle_s >= 3.0  # the speed needs ~3 s from rest


def test_objective_is_the_mean_floored_relative_error():
    rig = get_rig("walker")
    steps = pd.DataFrame({"frequency_hz": [23.0, 65.0], "body_speed_mm_s": [-25.7, 156.3 * 1.1]})
    j, parts = rig.objective(steps, TARGETS)
    assert parts["23 Hz"] == pytest.approx(10.0 / 35.7)
    assert parts["65 Hz"] == pytest.approx(0.1)
    assert j == pytest.approx((10.0 / 35.7 + 0.1) / 2)
    small = parse_targets({"rig": "walker", "speed_mm_s": {10: 2.0}}, "<test>")
    j, _ = rig.objective(pd.DataFrame({"frequency_hz": [10.0], "body_speed_mm_s": [12.0]}), small)
    assert j == pytest.approx(10.0 / 20.0)  # floored at 20 mm/s
    j, _ = rig.objective(pd.DataFrame({"frequency_hz": [10.0], "body_speed_mm_s": [math.nan]}), small)
    assert j == 10.0


def test_evaluator_and_written_protocol_carry_the_values(tmp_path):
    """One short evaluation (the speeds come back per frequency), then the written protocol builds a walker
    scene with the fitted foot mass and friction."""
    from dataclasses import replace

    from beambench.acquisition.protocol.schema import load_protocol
    from beambench.backends.sim import build_scene
    from beambench.session.slices import sim_slice

    rig = get_rig("walker")
    # the effective walker (PRB3 legs): the physical set's rod legs buckle under this robot (docs/contact-twin.md)
    base = replace(rig.base(TARGETS), model="prb3", params="paper")
    values = {"foot_mass": 0.004, "friction": 0.45}
    out = rig.simulate(base, values, [23.0, 65.0], base.sim.replace(settle_s=0.3, record_s=0.3, timestep=1e-4))
    steps = pd.DataFrame(out["steps"])
    assert list(steps["frequency_hz"]) == [23.0, 65.0]
    assert steps["body_speed_mm_s"].notna().all() and (steps["body_height_mm"] > 30).all()
    path = rig.write(base, values, out["extras"], TARGETS, tmp_path, "cal")
    assert path.exists()
    scene = build_scene(sim_slice(load_protocol(path)[0]))
    assert (scene.rig.foot_mass, scene.rig.friction) == (pytest.approx(0.004), pytest.approx(0.45))


def test_on_the_physical_set_the_values_go_into_its_walker_block(tmp_path):
    """The physical set's rig block is the contact rig's; the walker scene reads its walker block, so the fitted
    foot mass and friction must land there, in the evaluation and in the written protocol alike."""
    from beambench.acquisition.protocol.schema import load_protocol
    from beambench.backends.sim import build_scene
    from beambench.session.slices import sim_slice
    from beambench.sim.models.params import load_params

    rig = get_rig("walker")
    base = rig.base(TARGETS)
    prior = load_params(base.params, model="rod")
    assert prior.walker, "the shipped walker sweep runs the physical set, which has a walker block"
    values = {"foot_mass": 0.0061, "friction": 0.37}
    path = rig.write(base, values, {}, TARGETS, tmp_path, "cal")
    scene = build_scene(sim_slice(load_protocol(path)[0]))
    assert (scene.rig.foot_mass, scene.rig.friction) == (pytest.approx(0.0061), pytest.approx(0.37))
    assert scene.rig.foot_mass != pytest.approx(float(prior.walker.get("foot_mass", 0.0)))


def test_landmark_targets_add_their_grid_and_are_scored_and_judged():
    """`reverses_at_hz` / `peak_at_hz`: the calibrator runs a 2 Hz grid ± 8 Hz around each; the objective scores a
    landmark at its tolerance as a speed at its ± 30 % (0.3), a missing one as MISSING_LANDMARK; the verdict judges
    each landmark ± tolerance_hz."""
    from beambench.studies.twin_calibration.targets import CalibrationInputError
    from beambench.studies.twin_calibration.walker import MISSING_LANDMARK, walker_checks

    t = parse_targets(
        {"rig": "walker", "speed_mm_s": {23: -35.7}, "reverses_at_hz": 27, "peak_at_hz": 62, "tolerance_hz": 3},
        "<test>",
    )
    freqs = set(t.frequencies)
    assert {19.0, 27.0, 35.0, 54.0, 62.0, 70.0, 23.0} <= freqs and 18.0 not in freqs and 72.0 not in freqs
    assert (
        t.table.set_index("frequency_hz").loc[27.0, "body_speed_mm_s"]
        != t.table.set_index("frequency_hz").loc[27.0, "body_speed_mm_s"]
    )  # NaN: a grid row is not a speed target
    rig = get_rig("walker")
    f = t.frequencies
    # a twin curve reversing at 30 Hz (3 Hz = the tolerance off) and peaking at 62; -35.7 at 23 Hz exactly
    v = [(-35.7 / (23 - 30)) * (x - 30) if x < 46 else 150 - 0.5 * (x - 62) ** 2 for x in f]
    steps = pd.DataFrame({"frequency_hz": f, "body_speed_mm_s": v})
    j, parts = rig.objective(steps, t)
    assert parts["23 Hz"] == pytest.approx(0.0, abs=1e-9)
    assert parts["reverses_at_hz"] == pytest.approx(0.3)
    assert parts["peak_at_hz"] == pytest.approx(0.0, abs=1e-6)
    assert j == pytest.approx(0.1, abs=1e-6)  # the mean of the three parts
    backward = pd.DataFrame({"frequency_hz": f, "body_speed_mm_s": [-50.0] * len(f)})
    _, parts = rig.objective(backward, t)
    assert parts["reverses_at_hz"] == MISSING_LANDMARK and parts["peak_at_hz"] == MISSING_LANDMARK
    checks = {c.name: c for c in walker_checks(t)}
    rev = checks["speed reverses (backward → forward)"]
    assert rev.tolerance == 3.0 and rev.met(rev.measure(steps))  # 3 Hz off: at the tolerance
    assert not rev.met(rev.measure(backward))
    with pytest.raises(CalibrationInputError, match="speed_mm_s: missing"):
        parse_targets({"rig": "walker"}, "<test>")
    with pytest.raises(CalibrationInputError, match="reverses_at_hz"):
        parse_targets({"rig": "walker", "reverses_at_hz": "soon"}, "<test>")
