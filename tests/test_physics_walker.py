"""Walker scene physics: statics, symmetry, momentum, and convergence of the walking speed."""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np
import pytest

from beambench.sim.engine.stepping import quiet_mujoco_warnings
from beambench.sim.models.params import load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.scene_params import WalkerParams
from beambench.sim.scenes import walker
from beambench.sim.scenes.walker import WalkerLegError, WalkerSim, check_leg_model, measure_speed
from beambench.sim.scenes.walker_batch import steady_speeds
from test_walker_leg_statics import walker_normal_forces

BEAM = make_beam_model("prb3", load_params())
G = 9.81


def test_standing_walker_rests_on_feet_and_wheels_with_its_weight():
    """Motor off, after the preroll (quenched, then free): the contact normal forces carry the whole weight
    within 1 %; the cart's share is on the wheels (cart straight above them), the rest on the feet; and it
    stands: the body moves < 1 mm in the next 0.2 s. (It does not stand still: the soles creep outward through
    MuJoCo's soft friction and the body sinks ~2 mm/s, slowing to ~1 mm/s after 2 s.)"""
    sim = WalkerSim(BEAM, 90.0)
    m = sim.physics.model
    total = float(m.body_subtreemass[m.body("walker").id])
    normal = walker_normal_forces(sim)
    assert normal["sole"] + normal["wheel"] == pytest.approx(total * G, rel=0.01)
    assert normal["wheel"] == pytest.approx(sim.rig.cart_mass * G, rel=0.05)
    body = sim.advance_to(0.2).channels["markers"][:, 0]
    assert np.abs(body - body[0]).max() < 1e-3


def test_walker_builds_the_physical_rod_legs_and_refuses_unknown_models():
    """The walker's legs are the contact rig's physical rod (rod5g, sim_backend/rod_physical.yaml), with
    the set's walker block; a name no model family claims is a one-line WalkerLegError."""
    physical = load_params("physical", model="rod")
    sim = WalkerSim(make_beam_model("rod5g", physical), 90.0)
    assert sim.rig == WalkerParams.with_overrides(physical.walker)
    assert sum(1 for j in range(sim.physics.model.njnt) if sim.physics.model.joint(j).name.startswith("left_")) == 15
    sim.physics.close()
    with pytest.raises(WalkerLegError, match="unknown beam model"):
        check_leg_model("beam7")


def test_named_parameter_sets():
    assert WalkerParams.named("calibrated") == WalkerParams()
    guesses = WalkerParams.named("paper_guesses")
    assert guesses.foot_mass == pytest.approx(0.020) and guesses.rotor_inertia == pytest.approx(1.35e-5)
    with pytest.raises(ValueError, match="paper_guesses"):
        WalkerParams.named("nope")


def _run(wp: WalkerParams, f: float, t_end: float):
    sim = WalkerSim(BEAM, 90.0, wp)
    sim.set_frequency(f)
    return sim, sim.advance_to(t_end)


# The model is exactly mirror-symmetric: with Newton (a direct solve of the constraints) a mirrored walker repeats
# the other's motion to round-off. The shipped PGS sweeps the contacts in a fixed order (left sole before right) and
# stops at its tolerance (1e-8), so a mirror image differs by that much per step, which the chaotic gait grows: the
# bounds for the shipped solver are those differences measured (8.9e-7 m over 0.8 s, 6.2e-8 m over 2.5 s) with
# ~10x margin, still three to four orders below the motions checked.
SYMMETRY = {"newton": (mujoco.mjtSolver.mjSOL_NEWTON, 1e-9, 1e-9), "pgs (shipped)": (walker.SOLVER, 1e-5, 1e-6)}


@pytest.mark.parametrize("solver", list(SYMMETRY))
def test_mirror_image_walker_drifts_sideways_the_other_way(solver: str, monkeypatch: pytest.MonkeyPatch):
    """Mirroring the robot across its sagittal plane (both legs' chirality swapped, the flat motor's spin
    reversed) mirrors the motion: same forward path, opposite sideways drift (lateral slide freed). Checked
    over 0.8 s from rest with the crank ramping at 50 turn/s² (40 Hz at 0.8 s): the gait is chaotic once it walks,
    so round-off differences grow ~100× per 0.3 s after that (a faster ramp walks sooner and grows them sooner)."""
    which, tol, _ = SYMMETRY[solver]
    monkeypatch.setattr(walker, "SOLVER", which)
    base = {"motor_flat": 1.0, "lateral_free": 1.0, "timestep": 1e-4, "vel_ramp_rate": 50.0}
    a = replace(WalkerParams(), left_chirality=1.0, right_chirality=1.0, spin=-1.0, **base)
    b = replace(WalkerParams(), left_chirality=-1.0, right_chirality=-1.0, spin=1.0, **base)
    sa, ta = _run(a, 40.0, 0.8)
    _, tb = _run(b, 40.0, 0.8)
    assert sa.physics.model.opt.solver == which
    pa, pb = ta.channels["markers"][:, 0], tb.channels["markers"][:, 0]
    assert np.abs(pa[:, 1]).max() > 5e-3  # a real sideways drift (m) ...
    assert np.abs(pa[:, 1] + pb[:, 1]).max() < tol  # ... mirrored
    assert np.abs(pa[:, 0] - pb[:, 0]).max() < tol
    assert np.abs(pa[:, 2] - pb[:, 2]).max() < tol


@pytest.mark.parametrize("solver", list(SYMMETRY))
def test_symmetric_walker_does_not_drift_sideways_or_roll_at_23_hz(solver: str, monkeypatch: pytest.MonkeyPatch):
    """The paper's mirrored legs (φ = ∓90°) with the offset mass turning in the sagittal plane: a sagittal
    mirror symmetry, so even with the lateral slide freed the 23 Hz gait keeps y = 0 and no roll. (At 40 Hz
    and above this symmetric gait is unstable: round-off grows into a sideways drift / a few-mrad roll.)"""
    which, _, tol = SYMMETRY[solver]
    monkeypatch.setattr(walker, "SOLVER", which)
    sim, tr = _run(replace(WalkerParams(), lateral_free=1.0), 23.0, 2.5)
    assert sim.physics.model.opt.solver == which
    assert np.abs(tr.channels["markers"][:, 0, 1]).max() < tol
    assert abs(sim.physics.data.qpos[sim.physics.model.joint("roll").qposadr[0]]) < tol
    assert np.ptp(tr.channels["markers"][:, 0, 0]) > 5e-3  # while it does move (walks backward)


def test_shipped_solver_gives_the_direct_solvers_steady_speeds(monkeypatch: pytest.MonkeyPatch):
    """The shipped walker (rod5g legs, the physical set's walker block) with its PGS solver walks at Newton's steady
    speeds at 23 and 65 Hz within 2 % (measured 0.0 / 0.5 %: far inside the timestep's ≤ 10 %): the cheaper
    solver does not change the answer."""
    physical = load_params("physical", model="rod")
    beam, wp = make_beam_model("rod5g", physical), WalkerParams.with_overrides(physical.walker)
    sim = WalkerSim(beam, 90.0, wp)
    assert sim.physics.model.opt.solver == mujoco.mjtSolver.mjSOL_PGS
    sim.physics.close()
    shipped, _ = steady_speeds(beam, [23.0, 65.0], wp)
    monkeypatch.setattr(walker, "SOLVER", mujoco.mjtSolver.mjSOL_NEWTON)
    direct, _ = steady_speeds(beam, [23.0, 65.0], wp)
    assert shipped[0] < -20 and shipped[1] > 100  # walks backward at 23 Hz, forward at 65 Hz
    assert np.all(np.abs(shipped - direct) <= 0.02 * np.abs(direct)), (shipped, direct)


def test_without_friction_the_walker_cannot_walk():
    """Frictionless feet and wheels: no horizontal external force, so the horizontal momentum stays zero
    and the body only oscillates about a fixed place; with the default friction it walks. (The paper_guesses set's
    20 g feet: on the calibrated 3 g feet the frictionless legs splay and the 40 Hz offset mass, 25 N of
    centrifugal force against 3 N of weight, throws the robot over.)"""
    guesses = WalkerParams.named("paper_guesses")
    slip = replace(guesses, friction=0.0, timestep=1e-4)
    grip = replace(guesses, timestep=1e-4)
    with quiet_mujoco_warnings() as warned:  # a diverging run is reset by MuJoCo and would look like standing still
        v_slip, _ = measure_speed(BEAM, 40.0, slip, settle_s=0.5, record_s=1.0)
        v_grip, _ = measure_speed(BEAM, 40.0, grip, settle_s=0.5, record_s=1.0)
    assert not warned
    assert abs(v_grip) > 10e-3
    assert abs(v_slip) < 0.1 * abs(v_grip)  # ~1 mm/s of integrator drift against ~24 mm/s walking


@pytest.fixture(scope="module")
def steady():
    """Steady speeds (mm/s) at 23 and 65 Hz: the defaults, and half the timestep with half the contact time constant
    (each a batch from a settled robot, settle 3 s)."""
    d = WalkerParams()
    half = replace(d, timestep=d.timestep / 2, contact_timeconst=d.contact_timeconst / 2)
    return steady_speeds(BEAM, [23.0, 65.0], d)[0], steady_speeds(BEAM, [23.0, 65.0], half)[0]


def test_walking_speed_is_converged_in_the_timestep_and_contact_stiffness(steady):
    """Half the timestep and half the contact time constant move the steady speeds by ≤ 5 %."""
    v1, v2 = steady
    assert np.all(np.abs(v1 - v2) <= 0.05 * np.abs(v2))


def test_default_walker_walks_backward_at_23_hz_and_forward_at_65_hz_like_the_paper(steady):
    """Paper Sec. IV-B: −35.7 mm/s at 23 Hz, +156.3 at 65 Hz; the calibrated defaults give both signs and sizes
    within 30 %."""
    v, _ = steady
    assert v[0] < 0 < v[1]
    assert v[0] == pytest.approx(-35.7, rel=0.3)
    assert v[1] == pytest.approx(156.3, rel=0.3)


def test_protocol_selects_the_named_set_and_refuses_unknown_legs():
    """The shipped protocol runs the physical set's walker block on rod5g legs; `sim.model: prb3,
    sim.params: paper` the effective (PRB3) calibrated defaults, `walker_paper_guesses` the paper_guesses set; an
    unknown leg model is a one-line ConfigError before anything is built."""
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.backends.sim import build_scene
    from beambench.common.resources import shipped_dir
    from beambench.common.yaml_config import ConfigError
    from beambench.session.slices import sim_slice

    text = (shipped_dir("protocols") / "walker_sweep.yaml").read_text()
    shipped = build_scene(sim_slice(parse_protocol(text)))
    assert shipped.beam.name == "rod5g" and shipped.beam.params.name == "physical"
    assert shipped.rig == WalkerParams.with_overrides(load_params("physical", model="rod").walker)
    effective = text.replace("model: rod5g", "model: prb3").replace("params: physical", "params: paper")
    assert build_scene(sim_slice(parse_protocol(effective))).rig == WalkerParams.named("calibrated")
    guesses = build_scene(sim_slice(parse_protocol(effective.replace("params: paper", "params: walker_paper_guesses"))))
    assert guesses.rig == WalkerParams.named("paper_guesses")
    with pytest.raises(ConfigError, match=r"sim.model"):
        build_scene(sim_slice(parse_protocol(text.replace("model: rod5g", "model: beam7"))))


@pytest.mark.parametrize(("motor_flat", "axis"), [(0.0, [0, 1, 0]), (1.0, [0, 0, 1]), (2.0, [1, 0, 0])])
def test_offset_mass_turns_in_the_plane_across_the_motor_axis(motor_flat, axis):
    """The rotor turns about y (0), z (1) or x (2): at every rotor angle the 40 g mass stays in the plane across
    that axis, at the offset radius from it (2 turned the mass in the x–y plane before the x axis was added)."""
    sim = WalkerSim(BEAM, 90.0, replace(WalkerParams(), motor_flat=motor_flat, preroll_s=0.0))
    m, d = sim.physics.model, sim.physics.data
    try:
        rotor, body = m.body("rotor").id, m.body("walker").id
        qadr = int(m.jnt_qposadr[m.joint("rotor").id])
        for angle in np.linspace(0.0, 2 * np.pi, 7):
            d.qpos[qadr] = angle
            mujoco.mj_forward(m, d)
            rel = d.xmat[body].reshape(3, 3).T @ (d.xipos[rotor] - d.xpos[rotor])  # mass centre in the body frame
            assert float(np.dot(rel, axis)) == pytest.approx(0.0, abs=1e-9)
            assert float(np.linalg.norm(rel)) == pytest.approx(sim.rig.eccentric_radius, rel=1e-6)
    finally:
        sim.physics.close()
