"""The sole-plate contact's compliance as a physical stiffness: MuJoCo's soft contact acts on the contact point's
effective mass m_eff = 1/(J M⁻¹ Jᵀ) like a spring K = m_eff·ω² with ω = (d/dmax)/(tc·ζ), and the shipped time
constant's K lies inside the stiffness range that ``rod_physical.yaml``'s ``rig.contact_timeconst`` bound states
(7e3–1.2e5 N/m: a printed TPU 95A corner on the load-cell plate)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from beambench.sim.models.params import load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.scene_params import RigParams
from beambench.sim.scenes.contact_rig import ContactRigSim

K_RANGE = (7e3, 1.2e5)  # N/m, the physical range the bound's source argues


def _resting(rig_over: dict | None = None, timestep: float = 5e-5) -> ContactRigSim:
    """The shipped contact twin settled on the plate (preloaded), stage held."""
    params = load_params("physical", model="rod")
    rig = RigParams.with_overrides({**params.rig, **(rig_over or {})})
    return ContactRigSim(make_beam_model("rod5g", params), 90.0, None, rig=rig, timestep=timestep)


def _normal_row(m: mujoco.MjModel, d: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    """The contact normal's Jacobian row (into the plate, world frame) and M⁻¹ Jᵀ."""
    c = d.contact[0]
    sole = m.geom("sole").id
    body = m.geom_bodyid[sole]
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    mujoco.mj_jac(m, d, jp, jr, c.pos, body)
    n = np.array([0.0, 0.0, -1.0])  # the sole moves down into the plate
    row = n @ jp
    minv_jt = np.zeros((1, m.nv))
    mujoco.mj_solveM(m, d, minv_jt, row[None])
    return row, minv_jt[0]


def effective_mass(sim: ContactRigSim) -> float:
    """m_eff = 1 / (J M⁻¹ Jᵀ) along the contact normal at the resting contact (kg)."""
    m, d = sim.physics.model, sim.physics.data
    mujoco.mj_forward(m, d)
    assert d.ncon == 1, "the shipped foot rests on the plate (preload)"
    row, minv_jt = _normal_row(m, d)
    return float(1.0 / (row @ minv_jt))


def contact_stiffness(m_eff: float, rig: RigParams, d: float = 0.9, dmax: float = 0.95) -> float:
    """K = m_eff·ω², ω = (d/dmax)/(tc·ζ): MuJoCo's reference spring on the contact's effective mass (N/m)."""
    return m_eff * (d / dmax) ** 2 / (rig.contact_timeconst * rig.contact_dampratio) ** 2


def test_the_effective_mass_at_the_contact_lies_between_the_load_and_everything_hanging():
    sim = _resting()
    try:
        m_eff = effective_mass(sim)
        hanging = float(sum(sim.physics.model.body_mass)) - float(sim.physics.model.body("stage").mass[0])
    finally:
        sim.physics.close()
    assert sim.rig.foot_mass < m_eff < hanging, (m_eff, hanging)


def test_the_shipped_time_constant_is_a_contact_stiffness_inside_the_physical_range():
    params = load_params("physical", model="rod")
    bound = params.bounds["rig.contact_timeconst"]
    sim = _resting()
    try:
        m_eff = effective_mass(sim)
    finally:
        sim.physics.close()
    rig = sim.rig
    k = contact_stiffness(m_eff, rig)
    assert K_RANGE[0] <= k <= K_RANGE[1], k
    # the bound's ends are the stated stiffness range on this model's m_eff (within 15 %)
    soft = contact_stiffness(m_eff, RigParams(contact_timeconst=bound.max))
    stiff = contact_stiffness(m_eff, RigParams(contact_timeconst=bound.min))
    assert soft == pytest.approx(K_RANGE[0], rel=0.15) and stiff == pytest.approx(K_RANGE[1], rel=0.15), (soft, stiff)
    assert bound.contains(rig.contact_timeconst)


def test_an_impact_on_the_plate_compresses_the_contact_like_a_spring_on_the_effective_mass():
    """A small velocity kick into the plate from rest: the extra normal force over the extra penetration at the
    deepest point is K = m_eff·ω² (lightly damped, ζ 0.05, at the shipped stiffness: tc·ζ held), the depth is
    the one a spring K stores the kick's energy in, reached a quarter period π/(2ω) after the kick."""
    zeta = 0.05
    tc = load_params("physical", model="rod").rig["contact_timeconst"]
    sim = _resting({"contact_timeconst": tc / zeta, "contact_dampratio": zeta})
    m, d = sim.physics.model, sim.physics.data
    try:
        sim.physics.set_timestep(2e-6)  # resolves the impact (settled at the twin's own step)
        mujoco.mj_forward(m, d)
        m_eff = effective_mass(sim)
        k = contact_stiffness(m_eff, sim.rig)
        force = np.zeros(6)
        mujoco.mj_contactForce(m, d, 0, force)
        f0, r0 = force[0], -d.contact[0].dist
        _, minv_jt = _normal_row(m, d)
        v = 0.02  # m/s into the plate at the contact: the impulse m_eff·v along the normal
        d.qvel[:] += minv_jt * m_eff * v
        t_peak = df = dr = 0.0
        for i in range(int(0.006 / m.opt.timestep)):
            mujoco.mj_step(m, d)
            if d.ncon == 0:
                break
            mujoco.mj_contactForce(m, d, 0, force)
            if -d.contact[0].dist - r0 > dr:
                dr, df, t_peak = -d.contact[0].dist - r0, force[0] - f0, (i + 1) * m.opt.timestep
    finally:
        sim.physics.close()
    omega = np.sqrt(k / m_eff)
    assert df / dr == pytest.approx(k, rel=0.15), (df / dr, k)
    # energy: ½ m_eff v² = ½ K δ², less what the light damping takes by the deepest point (e^(−ζπ/2))
    assert dr == pytest.approx(v / omega * np.exp(-zeta * np.pi / 2), rel=0.12), (dr, v / omega)
    assert t_peak == pytest.approx(np.pi / (2 * omega), rel=0.2), (t_peak, np.pi / (2 * omega))
