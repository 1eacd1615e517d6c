"""The beam's pull on the contact rig's stage (``pull_x``, the channel behind the motor torque and the thermal
drift's power): the force along the stage's travel, whatever way the clamp turns the beam's section."""

from __future__ import annotations

import mujoco
import numpy as np

from beambench.sim.models.params import load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.scene_params import RigParams
from beambench.sim.scenes.contact_rig import ContactRigSim


def _rig(clamp_roll_deg: float, dt: float, gap_m: float = 0.002) -> ContactRigSim:
    beam = make_beam_model("rod5g", load_params("physical", model="rod"))
    rig = RigParams.with_overrides({**beam.params.rig, "clamp_roll_deg": clamp_roll_deg})
    return ContactRigSim(beam, 90.0, gap_m, rig=rig, timestep=dt)


def _pull_and_controls(sim: ContactRigSim, t_end: float) -> tuple[np.ndarray, np.ndarray]:
    """Advance ``sim`` to ``t_end``: the new rows' ``pull_x`` and the controls its physics was stepped with, one
    row a step (watched on ``physics.step``)."""
    physics = sim.physics
    step, applied = physics.step, []

    def watched(ctrl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        applied.append(np.array(ctrl, copy=True))
        return step(ctrl)

    physics.step = watched  # type: ignore[method-assign]
    try:
        pull = sim.advance_to(t_end).channels["pull_x"]
    finally:
        del physics.step  # the class's own again
    return pull, np.concatenate(applied)


def test_a_hanging_beam_pulls_the_held_stage_along_its_travel_by_nothing_at_any_clamp_roll():
    # the beam and its 30 g frame hang from the clamp: their weight (~0.34 N) is vertical, so the stage, held
    # still, feels no force along x (the plate 50 mm down, out of reach); a sensor read in the clamp's turned
    # frame reported the weight as pull_x
    for roll in (0.0, 90.0):
        sim = _rig(roll, 2e-4, gap_m=0.05)
        rows = sim.advance_to(1.0).channels["pull_x"]
        assert np.abs(rows[-100:]).max() < 0.02, (roll, rows[-5:])  # the weight: 0.34 N


def test_the_pull_is_the_clamped_subtrees_force_on_the_stage_to_first_order_in_the_timestep():
    """Against MuJoCo's own interaction force at the clamp (``cfrc_int`` after ``mj_rnePostConstraint``, world x),
    driven at 25 Hz with the foot on the plate: the two differ only by the step's discretisation (the step's
    realised acceleration vs the explicit one), which shrinks with the timestep."""
    diffs = []
    for dt in (2e-4, 5e-5):
        sim = _rig(90.0, dt)
        sim.set_frequency(25.0)
        sim.advance_to(1.5)
        snap = sim.snapshot()
        new, ctrl = _pull_and_controls(sim, 1.7)
        sim.restore(snap)
        assert len(ctrl) == len(new)
        m, d = sim.physics.model, sim.physics.data
        clamp = m.body("clamp").id
        ref = np.empty(len(new))
        for k in range(len(new)):
            d.ctrl[:] = ctrl[k]
            mujoco.mj_forward(m, d)
            mujoco.mj_rnePostConstraint(m, d)
            ref[k] = -d.cfrc_int[clamp, 3]  # the stage's force on the clamped subtree, world x; the pull is minus it
            mujoco.mj_step(m, d)
        assert np.abs(ref).max() > 0.1  # the drive loads the stage: a real comparison
        diffs.append(float(np.sqrt(np.mean((new - ref) ** 2)) / np.abs(ref).max()))
    assert diffs[0] < 0.06 and diffs[1] < 0.025, diffs
    assert diffs[1] < diffs[0] / 2, diffs  # converging with the timestep
