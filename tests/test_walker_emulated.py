"""The walker on `--backend emulated`: the real ODrive CAN driver against the emulated ODrive playing the walker's
Maxon EC 45 flat (from calibration/rig.yaml's ``walker:`` section), Motive and the load-cell MCU emulated, all
driven by the walker scene; two steps end to end into a session file."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.acquisition.hub import Hub
from beambench.acquisition.protocol.plan import motor_limits, plan
from beambench.acquisition.protocol.schema import load_rig_file, parse_protocol
from beambench.acquisition.runner import Runner
from beambench.backends.emulated import build_emulated_rig
from beambench.backends.hardware import DEFAULT_RIG_FILE
from beambench.session.slices import sim_slice
from beambench.sinks.session_file.reader import read_session
from beambench.sinks.session_file.writer import SessionWriter

PROTOCOL = """
name: walker_emu
rig: walker
sweep: {frequencies: [20, 40]}
settle_s: 0.6
record_s: 1.0
limits: {max_frequency_hz: 80, max_current_a: 2.0, max_amplitude_mm: 3}
sim: {model: prb3, timestep: 0.0001, seed: 1}
"""


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    protocol = parse_protocol(PROTOCOL)
    rig = build_emulated_rig(sim_slice(protocol))
    rig.open()
    path = tmp_path_factory.mktemp("walker_emu") / "walker.h5"
    general = {"protocol": PROTOCOL, "backend": "emulated", "identity": rig.identity()}
    writer = SessionWriter(path, general)
    hub = Hub([writer], critical=(writer,))
    hub.open([s.describe() for s in rig.streams])
    result = Runner(rig, hub, plan(protocol), motor_limits(protocol), poll_s=0.1).run()
    assert result.status == "completed", result.message
    return rig, read_session(path)


def test_the_emulated_odrive_plays_the_walker_motor(session):
    rig, _ = session
    cfg = rig.peers[0].odrive.config
    drive = load_rig_file(DEFAULT_RIG_FILE).walker
    assert (cfg.pole_pairs, cfg.feedback) == (8, "hall")
    assert cfg.torque_constant == pytest.approx(drive.torque_constant_nm_a)
    assert cfg.inertia == pytest.approx(drive.rotor_inertia_kg_m2)


def test_walker_runs_end_to_end_and_the_motor_holds_each_step(session):
    _, s = session
    motor = s.streams["motor"]
    vel = np.asarray(motor.columns["velocity"]).ravel()
    assert np.median(vel[vel > 30]) == pytest.approx(40.0, abs=0.5)  # the 40 Hz step (after the ramp's overshoot)
    iq = np.asarray(motor.columns["iq_measured"]).ravel()
    assert np.nanmax(np.abs(iq)) <= 2.0 + 1e-6  # within the protocol's limit (the ODrive saturates at it)
    assert np.median(vel[(vel > 15) & (vel < 25)]) == pytest.approx(20.0, abs=0.5)  # and the 20 Hz step
    body = np.asarray(s.streams["mocap"].columns["data"])[:, 0, :]
    assert np.ptp(body[np.isfinite(body[:, 0])], axis=0).max() > 1e-3  # the walker's body moved (m)
