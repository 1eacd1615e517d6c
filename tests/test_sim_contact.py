"""Contact rig physics seen through the sim devices: stage tracking, plate contact vs gap, walker scene."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.acquisition.batch import Batch
from beambench.acquisition.capabilities import MotorLimits
from beambench.acquisition.forces.loadcell_calibration import default_calibration
from beambench.acquisition.protocol.schema import parse_protocol
from beambench.acquisition.streams import WALKER_MARKERS
from beambench.backends.sim import build_sim_rig
from beambench.session.slices import sim_slice


def sweep(text: str, steps: list[tuple[float, float, float]]) -> tuple[list[dict[str, Batch]], object]:
    """Run (frequency, settle_s, record_s) steps; returns the recorded window of each step per stream."""
    rig = build_sim_rig(sim_slice(parse_protocol(text)))
    rig.open()
    rig.motor.arm(MotorLimits(80.0, 10.0, 2.0))
    windows = []
    for f, settle, record in steps:
        rig.motor.set_frequency(f)
        rig.clock.wait(settle)
        for s in rig.streams:
            s.read()
        got: dict[str, list[Batch]] = {s.name: [] for s in rig.streams}
        for _ in range(round(record / 0.1)):
            rig.clock.wait(0.1)
            for s in rig.streams:
                got[s.name].append(s.read())
        windows.append({k: Batch.concat(v) for k, v in got.items()})
    rig.motor.idle()
    rig.close()
    return windows, rig


def sine_fit(t: np.ndarray, x: np.ndarray, f0: float) -> tuple[float, float]:
    """Least-squares sine fit, frequency refined on a fine grid around ``f0``: (frequency, amplitude)."""
    best = (np.inf, f0, 0.0)
    for f in np.linspace(f0 - 0.3, f0 + 0.3, 301):
        a = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t)])
        coef, *_ = np.linalg.lstsq(a, x, rcond=None)
        r = float(np.sum((a @ coef - x) ** 2))
        if r < best[0]:
            best = (r, f, float(np.hypot(coef[0], coef[1])))
    return best[1], best[2]


def test_stage_follows_the_commanded_frequency_and_amplitude():
    freqs = [3.0, 17.0, 40.0]
    windows, _ = sweep("sweep: {frequencies: [1]}\nsim: {seed: 4}\n", [(f, 0.8, 1.0) for f in freqs])
    for f, w in zip(freqs, windows):
        m = w["mocap"]
        x = m.columns["data"][:, 0, 0]  # stage marker, noisy as Motive
        t = (m.host_time_ns - m.host_time_ns[0]) * 1e-9
        f_meas, amp = sine_fit(t, x, f)
        assert abs(f_meas - f) < 0.1
        assert abs(amp - 2e-3) / 2e-3 < 0.02
        assert np.ptp(m.columns["data"][:, 0, 1:]) < 1e-3  # the stage moves along x only


def plate_force(w: dict[str, Batch]) -> np.ndarray:
    return default_calibration().force_from_counts(w["loadcell"].columns["data"])


@pytest.mark.parametrize("freq", [10.0, 25.0, 40.0])
def test_foot_touches_the_plate_at_1mm_gap_but_not_at_the_papers_5p5mm(freq):
    steps = [(freq, 0.8, 0.5)]
    near, _ = sweep("sweep: {frequencies: [1]}\nsim: {plate_gap_mm: 1.0, noise: false}\n", steps)
    far, _ = sweep("sweep: {frequencies: [1]}\nsim: {plate_gap_mm: 5.5, noise: false}\n", steps)
    f_near, f_far = plate_force(near[0]), plate_force(far[0])
    # 1 mm: the sagging foot (≈ 1.1 mm under gravity) presses on the plate; the load cells see it
    assert f_near[:, 0].max() > 0.2 and f_near[:, 0].mean() > 0.02
    assert np.all(f_near[:, 0] > -1e-3)  # a plate only pushes
    assert np.abs(f_near[:, 1]).max() <= 0.5 * f_near[:, 0].max() + 0.02  # friction cone, μ = 0.5
    # 5.5 mm (the paper's h'): the PRB3 foot never reaches the plate
    assert np.all(np.abs(f_far) < 1e-3)
    foot_z = far[0]["mocap"].columns["data"][:, 2, 2]
    assert foot_z.min() > -(0.0665 + 0.0055) + 1e-3


def test_walker_scene_runs_with_its_markers_and_tare_only_loadcells():
    text = "rig: walker\nsweep: {frequencies: [1]}\nlimits: {max_frequency_hz: 80}\nsim: {seed: 1}\n"
    windows, rig = sweep(text, [(30.0, 0.7, 0.5)])  # ramp 50 turn/s² reaches 30 Hz in 0.6 s
    w = windows[0]
    assert rig.mocap.describe().columns["data"].labels == WALKER_MARKERS
    data = w["mocap"].columns["data"]
    assert np.all(np.isfinite(data))
    feet_z = data[:, 1:, 2]
    assert np.abs(feet_z.mean()) < 2e-3  # feet on the floor (sole bottom at z = 0, ±contact, ±noise)
    assert 0.05 < data[:, 0, 2].mean() < 0.075  # body upright at leg height
    counts = w["loadcell"].columns["data"]
    assert np.abs(counts.mean(axis=0) - default_calibration().tare).max() < 5  # no plate: tare + noise
    assert np.mean(w["motor"].columns["velocity"]) == pytest.approx(30.0, abs=0.05)
    assert rig.identity()["model"]["scene"] == "walker"


def test_walker_reverses_direction_between_23_and_65_hz():
    """Like the paper (−35.7 mm/s at 23 Hz, +156.3 at 65 Hz): at the scene's (converged, calibrated) defaults it
    walks backward at 23 Hz and forward at 65 Hz (sizes: tests/test_physics_walker.py, from a steady state)."""
    from beambench.sim.models.params import load_params
    from beambench.sim.models.registry import make_beam_model
    from beambench.sim.scenes.walker import WalkerSim, measure_speed

    beam = make_beam_model("prb3", load_params())
    assert WalkerSim(beam, 90.0).physics.timestep == 1.2e-4  # the converged default (no protocol override)
    v23, _ = measure_speed(beam, 23.0)
    v65, _ = measure_speed(beam, 65.0)
    assert v23 < -8e-3 and v65 > 5e-3
