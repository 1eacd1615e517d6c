"""The physical twin: the shipped bounded beam against hand calculations, its friction bound in a
contact run, and the same beam object on both rigs."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from beambench.sim.models.params import load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.models.rod import RodParams, add_rod, natural_frequencies
from beambench.sim.scene_params import RigParams
from beambench.sim.scenes.contact_rig import ContactRigSim

PHYSICAL = load_params("physical", model="rod")
MODEL = "rod5g"  # the shipped protocols' model (protocols/contact_sweep.yaml, walker_sweep.yaml)


def _compliance(rod: RodParams, twist_deg: float, roll_deg: float) -> np.ndarray:
    """Tip compliance [[xx, xz], [zx, zz]] (m/N) of a linear twisted cantilever under a tip force, by hand:
    C = ∫₀ᴸ (L − s)² R(θ) diag(1/EI_w, 1/EI_s) R(θ)ᵀ ds, the section turned about the beam axis (+y) by
    α(s) = roll + φ·s/L, so its weak direction (the thickness, x at the clamp) is (cos α, −sin α) in (x, z).
    Shear and torsion do not enter (a force through the section's centre)."""
    s = np.linspace(0.0, rod.length, 4001)
    th = -(math.radians(roll_deg) + math.radians(twist_deg) * s / rod.length)
    c, n = np.cos(th), np.sin(th)
    a, b = 1 / rod.ei_weak, 1 / rod.ei_strong
    lever = (rod.length - s) ** 2
    xx = np.trapezoid(lever * (c * c * a + n * n * b), s)
    zz = np.trapezoid(lever * (n * n * a + c * c * b), s)
    xz = np.trapezoid(lever * c * n * (a - b), s)
    return np.array([[xx, xz], [xz, zz]])


def _rod_with_tip_mass(roll_deg: float, tip_mass: float, gravity: bool):
    """The shipped rod clamped at the origin, its section turned by ``roll_deg`` at the clamp, a point mass at
    the tip (no foot: the hand formulas are for a load at the tip)."""
    rod = RodParams.from_beam(PHYSICAL, n_segments=5, nodes="gauss")
    spec = mujoco.MjSpec()
    spec.option.gravity = [0, 0, -9.81 if gravity else 0.0]
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_DISCRETE
    spec.option.timestep = 1e-3
    roll = math.radians(roll_deg)
    clamp = spec.worldbody.add_body(name="clamp", quat=[math.cos(roll / 2), 0, math.sin(roll / 2), 0])
    sites = add_rod(clamp, rod, PHYSICAL.twist_deg)
    spec.body(sites.tip_body).add_geom(
        type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[1e-4, 0, 0], mass=tip_mass, contype=0, conaffinity=0
    )
    m = spec.compile()
    return rod, m, mujoco.MjData(m), sites


@pytest.mark.parametrize("roll_deg", [0.0, 90.0])
def test_static_sag_under_a_small_tip_load_is_the_twisted_cantilever_formula(roll_deg):
    """2 g at the tip (linear regime), no beam weight: the vertical (and the bend–twist coupled sideways) tip
    deflection equal F·C_zz (F·C_xz) of the hand formula within 3 %; the turned clamp (flat face horizontal)
    sags ~4x more than the as-built one — why the contact rig needs it to reach the paper's h' = 5.5 mm."""
    tip_mass = 0.002
    rod, m, d, sites = _rod_with_tip_mass(roll_deg, tip_mass, gravity=True)
    m.body_mass[[m.body(b).id for b in sites.bodies if b != sites.tip_body]] = 0.0  # the hand formula: tip load only
    m.body_inertia[[m.body(b).id for b in sites.bodies if b != sites.tip_body]] = 1e-12
    dof = np.arange(m.nv)
    m.dof_damping[dof] = 1e-3  # settle fast (statics only)
    tip = m.site(sites.tip_site).id
    mujoco.mj_forward(m, d)
    p0 = d.site_xpos[tip].copy()
    for _ in range(3000):
        mujoco.mj_step(m, d)
    assert np.abs(d.qvel).max() < 1e-6
    delta = d.site_xpos[tip] - p0
    force = tip_mass * 9.81
    c = _compliance(rod, PHYSICAL.twist_deg, roll_deg)
    assert -delta[2] == pytest.approx(force * c[1, 1], rel=0.03)
    assert -delta[0] == pytest.approx(force * c[0, 1], rel=0.05, abs=2e-6)
    if roll_deg == 90.0:
        assert c[1, 1] > 3.5 * _compliance(rod, PHYSICAL.twist_deg, 0.0)[1, 1]


def test_first_natural_frequencies_with_a_tip_mass_are_the_hand_values():
    """20 g at the tip, no gravity: the two lowest bending frequencies are those of the 2 x 2 system
    K = C⁻¹ (hand compliance above) with the tip mass plus the Rayleigh share 33/140 of the beam's mass, within 5 %."""
    tip_mass = 0.020
    rod, m, _, _ = _rod_with_tip_mass(90.0, tip_mass, gravity=False)
    f = natural_frequencies(m)
    stiffness = np.linalg.inv(_compliance(rod, PHYSICAL.twist_deg, 90.0))
    mass = tip_mass + 33 / 140 * rod.mass
    hand = np.sqrt(np.linalg.eigvalsh(stiffness / mass)) / (2 * math.pi)
    assert f[:2] == pytest.approx(hand, rel=0.05)


def test_every_shipped_number_is_inside_its_physical_range():
    """The bounds block covers the issue's limits: friction <= 1.5, beta <= 0.02 s, h' = 5.5 +- 1 mm,
    the paper's foot (66.5 mm, 20 g), E of printed TPU 95A; and every bounded number lies inside."""
    assert PHYSICAL.out_of_bounds() == []
    b = PHYSICAL.bounds
    assert b["rig.friction"].max <= 1.5 and b["walker.friction"].max <= 1.5
    assert b["beam.beta"].max <= 0.02
    assert b["rig.plate_gap"].min >= 0.0045 and b["rig.plate_gap"].max <= 0.0065
    assert PHYSICAL.value("rig.foot_length") == 0.0665 and PHYSICAL.value("rig.foot_mass") == 0.020
    e = b["beam.material.youngs_modulus"]
    assert 35e6 <= e.min < e.max <= 70e6  # the range the paper's release fit implies (35 MPa vertical, 68 sideways)
    assert "release" in e.source and "Gent" in e.source and "datasheet" in e.source


def _hang(params: str, model: str, youngs_modulus: float | None = None) -> float:
    """How far the tip markers' centre moves when the release test's 200 g hangs from the tip (statics, m)."""
    from dataclasses import replace

    from beambench.sim.scenes.release import G, release_batch, release_models

    p = load_params(params, model="rod" if model.startswith("rod") else "prb3")
    if youngs_modulus is not None:
        p = replace(p, material=replace(p.material, youngs_modulus=youngs_modulus))
    models = release_models([make_beam_model(model, p)], twist_deg=90.0)
    rb = release_batch(models, 0.2 * G, 0.01, with_rest=True, nthread=1)
    return float(np.linalg.norm(rb.loaded[0].mean(axis=0) - rb.rest[0].mean(axis=0)))


def test_the_shipped_beam_hangs_like_the_papers_fitted_release():
    """The release test's 200 g: the shipped beam's tip moves within +-25 % of the paper's PRB3 fit (13.1 mm, the
    stand-in for the measured release), and so does the beam at either end of its modulus range."""
    paper = _hang("paper", "prb3")
    assert paper == pytest.approx(0.0131, abs=0.0002)
    assert _hang("physical", MODEL) == pytest.approx(paper, rel=0.25)
    e = PHYSICAL.bounds["beam.material.youngs_modulus"]
    for modulus in (e.min, e.max):
        assert _hang("physical", MODEL, modulus) == pytest.approx(paper, rel=0.25), modulus


def test_the_soles_tangential_force_never_exceeds_its_friction():
    """In a contact run at the sweep's transitions (18, 26, 40 Hz), the foot preloaded 0.3 mm onto the plate, at
    every step with the foot down, the contact force's tangential magnitude is at most friction x normal (the cone
    holds)."""
    from beambench.sim.scenes.contact_regimes import static_sag

    beam = make_beam_model(MODEL, PHYSICAL)
    gap = static_sag(beam, RigParams.with_overrides(PHYSICAL.rig), PHYSICAL.twist_deg) - 0.0003
    worst, steps_in_contact = 0.0, 0
    for f in (18.0, 26.0, 40.0):
        sim = ContactRigSim(beam, PHYSICAL.twist_deg, gap_m=gap)
        m, d = sim.physics.model, sim.physics.data
        sole, f6 = m.geom("sole").id, np.zeros(6)
        sim.set_frequency(f)
        sim.advance_to(1.0)
        for _ in range(2000):
            mujoco.mj_step(m, d)
            for i in range(d.ncon):
                if sole in (d.contact[i].geom1, d.contact[i].geom2):
                    mujoco.mj_contactForce(m, d, i, f6)
                    if f6[0] > 1e-3:
                        steps_in_contact += 1
                        worst = max(worst, math.hypot(f6[1], f6[2]) / f6[0])
        sim.physics.close()
    assert steps_in_contact > 500
    mu = RigParams.with_overrides(PHYSICAL.rig).friction
    assert worst <= mu * (1 + 1e-6)
    assert worst > 0.1 * mu  # the foot really pushes sideways


def test_the_same_beam_object_on_both_rigs():
    """One parameter object, one beam: the contact rig's beam and each walker leg have the same joints with
    the same stiffness and damping, and both scenes record the same parameter set."""
    from beambench.sim.scenes.walker import WalkerSim

    beam = make_beam_model(MODEL, PHYSICAL)
    contact = ContactRigSim(beam, 90.0)
    walker = WalkerSim(beam, 90.0)
    assert contact.beam.params is walker.beam.params is PHYSICAL

    def springs(m: mujoco.MjModel, prefix: str) -> np.ndarray:
        ids = [j for j in range(m.njnt) if m.joint(j).name.startswith(prefix)]
        return np.array([[m.jnt_stiffness[j], m.dof_damping[m.jnt_dofadr[j]]] for j in ids])

    rig = springs(contact.physics.model, "beam_")
    assert len(rig) == 15
    for leg in ("left_", "right_"):
        assert np.array_equal(springs(walker.physics.model, leg), rig)
    assert contact.identity()["params"] == walker.identity()["params"]
    contact.physics.close()
    walker.physics.close()
