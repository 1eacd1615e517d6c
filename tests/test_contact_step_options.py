"""The contact rig skips the MuJoCo pipeline stages its scene has nothing for: the same trajectory bit for bit as
with every stage on, and a stage the scene does use (the sole's travel stop is a joint limit) stays on."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from beambench.acquisition.protocol.schema import load_protocol
from beambench.backends.sim import build_scene
from beambench.session.slices import sim_slice
from beambench.sim.models.params import load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.scene_params import RigParams
from beambench.sim.scenes.contact_rig import ContactRigSim

ROOT = Path(__file__).resolve().parents[1]
OFF = mujoco.mjtDisableBit


def test_skipping_the_unused_stages_keeps_the_trajectory_bit_for_bit():
    protocol, _ = load_protocol(ROOT / "protocols" / "contact_sweep.yaml")
    scene = build_scene(sim_slice(protocol))
    opt = scene.physics.model.opt
    for stage in (OFF.mjDSBL_ISLAND, OFF.mjDSBL_LIMIT, OFF.mjDSBL_EQUALITY, OFF.mjDSBL_MIDPHASE):
        assert opt.disableflags & int(stage), stage  # the shipped twin has none of these
    scene.set_frequency(30.0)
    scene.advance_to(0.6)  # ramping up, the foot on the plate
    start = scene.snapshot()
    skipped = scene.advance_to(1.0)
    flags, opt.disableflags = opt.disableflags, 0
    scene.restore(start)
    every = scene.advance_to(1.0)
    opt.disableflags = flags
    assert (skipped.channels["force_nt"][:, 0] > 0).any()  # the contact is in the comparison
    for name, values in skipped.channels.items():
        np.testing.assert_array_equal(values, every.channels[name], err_msg=name)


def test_a_scene_with_a_joint_limit_keeps_its_limits():
    beam = make_beam_model("prb3", load_params("contact_paper"))
    rig = RigParams.with_overrides({"sole_stiffness": 200.0, "sole_damping": 2.0, "sole_travel": 2e-5})
    scene = ContactRigSim(beam, 90.0, 5.5e-3, 0.002, rig, timestep=1e-4)
    flags = scene.physics.model.opt.disableflags
    assert not flags & int(OFF.mjDSBL_LIMIT)  # the sole's travel stop is a limit row
    assert flags & int(OFF.mjDSBL_EQUALITY)  # what the scene lacks is still skipped
    scene.physics.close()


def test_a_state_restored_on_another_copy_of_a_loss_factor_scene_damps_at_its_drive_frequency():
    """A segment computed elsewhere hands its state to a fresh copy of the scene (``beambench run --scheduler``):
    the copy's beam dampers follow the restored drive frequency, so it continues with the same physics."""
    from dataclasses import replace

    params = replace(load_params("physical", "rod"), loss_factor=0.12)
    ran, fresh = (ContactRigSim(make_beam_model("rod5g", params), gap_m=0.01, timestep=1e-4) for _ in range(2))
    ran.set_frequency(26.0)
    ran.advance_to(0.05)
    fresh.restore(ran.snapshot())
    dofs = ran.damping.dofs
    np.testing.assert_array_equal(fresh.physics.model.dof_damping[dofs], ran.physics.model.dof_damping[dofs])
    assert fresh.physics.model.dof_damping[dofs].max() > 0
    np.testing.assert_array_equal(fresh.advance_to(0.1).channels["markers"], ran.advance_to(0.1).channels["markers"])
    for scene in (ran, fresh):
        scene.physics.close()
