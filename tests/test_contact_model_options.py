"""The contact twin's two model options for the box search: material damping with a frequency-independent loss
factor (``beam.loss_factor``) and the load frame as a rigid body of bounded inertia (``rig.frame_gyration``)."""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np
import pytest

from beambench.sim.models.hysteretic import HystereticDamping
from beambench.sim.models.params import load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.models.rod import natural_frequencies
from beambench.sim.scene_params import RigParams
from beambench.sim.scenes.contact_rig import ContactRigSim, build_contact_spec
from beambench.sim.scenes.release import build_release_spec

PHYSICAL = load_params("physical", "rod")


def _modal_damping(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """Natural frequencies (Hz) and modal damping ratios ζ = vᵀCv / 2ω (M-normalised modes, C = the dof dampers)."""
    f, vecs = natural_frequencies(model, modes=True)
    c = np.diag(model.dof_damping)
    w = 2 * np.pi * f
    return f, np.array([vecs[:, i] @ c @ vecs[:, i] / (2 * w[i]) for i in range(len(f))])


def test_a_loss_factor_damps_the_mode_at_the_drive_frequency_by_half_of_it_whatever_the_frequency():
    """Hysteretic damping: a mode driven at its own frequency gets ζ = η/2 (the material's), the first and the
    third mode alike; the stiffness-proportional β of the release fit gives the first mode ζ ~0.9 instead."""
    beam = make_beam_model("rod5g", PHYSICAL)
    model = build_release_spec(beam).compile()
    f, zeta_beta = _modal_damping(model)
    assert zeta_beta[0] == pytest.approx(0.94, abs=0.06)  # beta 8.7 ms at the free beam's 34 Hz mode
    eta = 0.1
    damping = HystereticDamping.of(model, eta)
    assert len(damping.dofs) == model.nv  # every hinge of the clamped beam is sprung
    for mode in (0, 2):
        damping.at(model, f[mode])
        _, zeta = _modal_damping(model)
        assert zeta[mode] == pytest.approx(eta / 2, rel=0.03), (mode, f[mode], zeta[: mode + 1])
    damping.at(model, 2 * f[0])  # driven at twice its frequency, the first mode is damped half as much
    assert _modal_damping(model)[1][0] == pytest.approx(eta / 4, rel=0.03)


def test_the_contact_rig_resets_the_beams_dampers_at_each_drive_frequency_and_only_the_beams():
    params = replace(PHYSICAL, loss_factor=0.12)
    scene = ContactRigSim(make_beam_model("rod5g", params), gap_m=0.01)
    m = scene.physics.model
    stage = m.jnt_dofadr[m.joint("stage").id]
    stage_damping = float(m.dof_damping[stage])
    dofs = scene.damping.dofs
    assert stage not in dofs and len(dofs) == 15  # rod5g: 5 joints x 3 hinges
    k = scene.damping.stiffness
    for hz in (10.0, 26.0, 40.0):
        scene.set_frequency(hz)
        np.testing.assert_allclose(m.dof_damping[dofs] * 2 * np.pi * hz / k, 0.12, rtol=1e-12)
        assert m.dof_damping[stage] == stage_damping
    scene.advance_to(0.05)  # it still steps
    assert np.isfinite(scene.physics.data.qpos).all()
    scene.physics.close()
    assert ContactRigSim(make_beam_model("rod5g", PHYSICAL), gap_m=0.01).damping is None  # off by default


def test_a_model_option_that_is_off_is_inside_its_bounds_and_one_that_is_on_must_be():
    assert PHYSICAL.out_of_bounds() == []
    assert PHYSICAL.bounds["beam.loss_factor"].min == pytest.approx(0.05)
    assert replace(PHYSICAL, loss_factor=0.1).out_of_bounds() == []
    bad = replace(PHYSICAL, loss_factor=0.5).out_of_bounds()
    assert len(bad) == 1 and bad[0].startswith("beam.loss_factor")
    bad = replace(PHYSICAL, rig={**PHYSICAL.rig, "frame_gyration": 0.05}).out_of_bounds()
    assert len(bad) == 1 and bad[0].startswith("rig.frame_gyration")


def _rig_model(gyration: float) -> mujoco.MjModel:
    rig = RigParams.with_overrides({**PHYSICAL.rig, "frame_gyration": gyration})
    return build_contact_spec(make_beam_model("rod5g", PHYSICAL), 90.0, 0.02, rig).compile()


def test_the_rigid_frame_keeps_the_mass_and_adds_inertia_that_lowers_every_natural_frequency():
    """The rigid frame carries rig.frame_mass with inertia m·r² at the frame's centroid; the total mass is the
    spread frame's. More inertia, same stiffness and gravity: no natural frequency rises (Rayleigh)."""
    spread = _rig_model(0.0)
    m_frame = float(PHYSICAL.rig["frame_mass"])
    total = float(spread.body_subtreemass[0])
    freqs = []
    for r in (0.010, 0.020, 0.033):
        model = _rig_model(r)
        body = model.body("load_frame")
        assert float(body.mass[0]) == pytest.approx(m_frame)
        np.testing.assert_allclose(body.inertia, m_frame * r**2, rtol=1e-9)
        assert float(model.body_subtreemass[0]) == pytest.approx(total, rel=1e-9)
        freqs.append(natural_frequencies(model)[1:6])  # the stage's slide (armature-heavy) aside
    for lo, hi in zip(freqs[1:], freqs[:-1]):
        assert np.all(lo <= hi * (1 + 1e-6)), (lo, hi)
    assert freqs[-1][0] < freqs[0][0] * 0.995  # and the frame's inertia shows in the lowest beam mode


def test_the_walkers_legs_take_the_same_loss_factor_at_its_drive_frequency():
    """The same beam on the walker: its two legs' hinges (and nothing else) damped at the rotor's frequency."""
    from beambench.sim.scenes.walker import WalkerSim

    sim = WalkerSim(make_beam_model("rod5g", replace(PHYSICAL, loss_factor=0.08)))
    m = sim.physics.model
    assert sim.damping is not None and len(sim.damping.dofs) == 30  # 2 legs x 5 joints x 3 hinges
    assert all(m.joint(j).name.startswith(("left_", "right_")) for j in range(m.njnt) if m.jnt_stiffness[j] > 0)
    for hz in (23.0, 65.0):
        sim.set_frequency(hz)
        np.testing.assert_allclose(m.dof_damping[sim.damping.dofs] * 2 * np.pi * hz / sim.damping.stiffness, 0.08)
    sim.physics.close()
