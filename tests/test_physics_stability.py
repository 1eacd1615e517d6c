"""No scene diverges at its default settings anywhere in 1–80 Hz."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from beambench.acquisition.protocol.schema import parse_protocol
from beambench.sim.scenes.free_beam import FREE_BEAM_SETTINGS, frequency_sweep
from beambench.sim.settings import SimSettings

FREQS = [1.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0]
BAD = (mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADQVEL, mujoco.mjtWarning.mjWARN_BADQPOS)


@pytest.mark.parametrize("model", ["prb3", "rod10"])
def test_free_beam_defaults_stay_bounded(model):
    """Default integrator and timestep of the free-beam scene; the tip stays within a beam length of its
    rest position and keeps moving with the drive (a frozen, warned-out run would also fail)."""
    r = frequency_sweep(model, FREQS, FREE_BEAM_SETTINGS.replace(settle_s=0.5, record_s=0.1), sample_dt=1e-3)
    assert r.ok.all()
    assert np.isfinite(r.tip).all()
    rest = np.array([0.0, 0.05, 0.0])
    assert np.linalg.norm(r.tip - rest, axis=2).max() < 0.05
    assert (np.ptp(r.tip[:, :, 0], axis=1) > 1e-4).all()


@pytest.mark.parametrize("rig", ["contact", "walker"])
def test_rig_scenes_at_their_defaults_stay_bounded(rig):
    """The protocol-driven scenes (the sim backend's default model, integrator and timestep policy), swept
    through 1–80 Hz in one run: no MuJoCo instability warning, finite and bounded marker paths."""
    from beambench.backends.sim import build_scene
    from beambench.session.slices import sim_slice

    scene = build_scene(sim_slice(parse_protocol(f"rig: {rig}\nsweep: {{frequencies: [1]}}\n")))
    t = scene.physics.time
    for f in FREQS:
        scene.set_frequency(f)
        t += 0.6
        traj = scene.advance_to(t)
        markers = traj.channels["markers"]
        assert np.isfinite(markers).all(), f"{rig}: non-finite markers at {f} Hz"
        assert np.abs(markers).max() < 10.0, f"{rig}: markers left the scene at {f} Hz"
    warn = scene.physics.data.warning
    assert all(warn[w].number == 0 for w in BAD), f"{rig}: MuJoCo instability warnings"


@pytest.mark.parametrize("integrator", ["implicitfast", "rk4"])
def test_recorded_rows_are_aligned_with_simulated_time(integrator):
    """Row k is the state at t = k·h: the stage sensor equals A·sin(2πft) at the row times to nanometres
    (a one-step lag between sensor and state rows would show as A·ω·h = 13 µm here)."""
    h = 1e-5 if integrator == "rk4" else 1e-4
    s = SimSettings(settle_s=0.05, record_s=0.1, timestep=h, integrator=integrator)
    r = frequency_sweep("prb3", [10.0, 40.0], s)
    assert r.ok.all()
    expected = 0.002 * np.sin(2 * np.pi * r.frequencies[:, None] * r.t[None, :])
    assert np.abs(r.stage - expected).max() < 1e-8


def test_a_diverging_batch_is_reported_not_logged_into_the_working_directory(tmp_path, monkeypatch):
    """MuJoCo's default warning handler prints and appends to MUJOCO_LOG.TXT in the working directory; the
    batch engine reports a diverged run in ``ok`` instead, and puts the user's handler back."""
    monkeypatch.chdir(tmp_path)
    before = mujoco.get_mju_user_warning()
    r = frequency_sweep("rod10", [40.0], SimSettings(settle_s=0.2, record_s=0.1, integrator="euler", timestep=2e-3))
    assert not r.ok[0]
    assert not list(tmp_path.iterdir())
    assert mujoco.get_mju_user_warning() is before
