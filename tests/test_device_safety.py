"""Device safety on the emulated rig (real drivers, emulated peers in their own process): forged NatNet frames
never reach the session and are counted; a load-cell board that falls silent ends the run as a fault, motor idle
first, the session saved; every driver's counters are in the session."""

from __future__ import annotations

import socket
import threading

import numpy as np
import pytest

from beambench.acquisition.hub import Hub
from beambench.acquisition.protocol.plan import motor_limits, plan
from beambench.acquisition.protocol.schema import parse_protocol
from beambench.acquisition.runner import Runner
from beambench.backends.emulated import build_emulated_rig
from beambench.devices.natnet import frame as nf
from beambench.devices.natnet import protocol as nn
from beambench.devices.natnet import wire as nw
from beambench.devices.odrive.cansimple import AxisState
from beambench.session.slices import sim_slice
from beambench.sinks.session_file.reader import read_session
from beambench.sinks.session_file.writer import SessionWriter, append_general

PROTOCOL = """
name: safety
sweep: {frequencies: [6]}
settle_s: 0.4
record_s: 2.5
sim: {seed: 3}
monitors: {mocap_lost_s: null}
"""


def _run(tmp_path, name, inject=None, during=None):
    protocol = parse_protocol(PROTOCOL)
    rig = build_emulated_rig(sim_slice(protocol), inject=inject)
    rig.open()
    path = tmp_path / name
    writer = SessionWriter(path, {"protocol": PROTOCOL, "backend": "emulated"})
    hub = Hub([writer], critical=(writer,))
    hub.open([s.describe() for s in rig.streams])
    stop = threading.Event()
    worker = threading.Thread(target=during, args=(rig, stop), daemon=True) if during else None
    if worker:
        worker.start()
    try:
        result = Runner(rig, hub, plan(protocol), motor_limits(protocol), poll_s=0.1).run()
    finally:
        stop.set()
        if worker:
            worker.join(5)
    append_general(path, rig.after_run())
    return result, rig, read_session(path)


def _forged_frame(number: int) -> bytes:
    """A well-formed NatNet 4.1 frame with the emulator's marker ids, every marker 9 m away."""
    markers = tuple(nf.LabeledMarker((1 << 16) | (i + 1), (9.0, 9.0, 9.0), 0.014, 2, 0.0) for i in range(3))
    return nn.encode(nf.FrameOfData(number, labeled_markers=markers, timestamp=number / 360), nw.V4_1)


@pytest.fixture(scope="module")
def forged_and_dropped(tmp_path_factory):
    """One run with a forger on loopback and three mocap frames dropped by the emulated Motive (the forger's
    frames are rejected by source before any frame bookkeeping, so the two faults do not mix)."""
    sent = {"n": 0}

    def forge(rig, stop):  # 300 frames within the run (it lasts > 2 s), so every one reaches an open socket
        target = rig.mocap.client.receive_address  # unicast frames arrive on the command socket
        assert target is not None
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            while sent["n"] < 300 and not stop.wait(0.002):
                s.sendto(_forged_frame(10_000 + sent["n"]), target)
                sent["n"] += 1

    tmp = tmp_path_factory.mktemp("forged")
    return sent, _run(tmp, "forged.h5", inject={"mocap_drop": {300, 301, 302}}, during=forge)


def test_forged_natnet_frames_are_dropped_and_counted(forged_and_dropped):
    """A forger on loopback streams valid frames (markers at 9 m) to the client's socket while the emulated
    Motive streams: none lands in the session, and the driver counts every one."""
    sent, (result, rig, s) = forged_and_dropped
    assert result.status == "completed", result.message
    assert sent["n"] == 300
    data = s.streams["mocap"].columns["data"]
    assert len(data) > 300 and np.nanmax(np.abs(data)) < 1.0  # no 9 m marker
    assert s.streams["mocap"].columns["frame"].max() < 10_000
    assert rig.mocap.counters.forged == sent["n"]
    assert int(s.general["devices"]["mocap"]["forged"]) == sent["n"]


def test_a_silent_load_cell_board_is_a_fault_that_idles_and_saves(tmp_path):
    """The board stops sending 1 s after the rig opened: the run ends as a fault (not ``completed``), the
    motor idled first, everything recorded before is in the file."""
    result, rig, s = _run(tmp_path, "silent.h5", inject={"loadcell_stop_s": 1.0})
    assert result.status == "fault", result.message
    assert "loadcell" in result.message and "silent" in result.message
    kinds = list(s.events["kind"])
    assert [k for k in kinds if k != "devices"][-2:] == ["idle", "fault"]
    assert rig.peers[0].odrive.snapshot()["state"] == AxisState.IDLE
    assert s.streams["motor"].columns["velocity_setpoint"][-1] == 0.0
    assert len(s.streams["loadcell"]) > 300  # the second before the silence is saved
    assert s.steps.iloc[0].status == "fault"


def test_every_driver_reports_its_counters_into_the_session(forged_and_dropped):
    _sent, (result, _rig, s) = forged_and_dropped
    assert result.status == "completed", result.message
    devices = s.general["devices"]
    assert set(devices) >= {"motor", "mocap", "loadcell"}
    for stream in ("motor", "mocap", "loadcell"):
        counts = devices[stream]
        assert {"received", "dropped", "garbled", "forged"} <= set(counts)
        assert int(counts["received"]) >= len(s.streams[stream]) > 0
    assert int(devices["mocap"]["dropped"]) == 3


def test_the_emulated_peers_run_in_their_own_process_and_the_heartbeat_timeout_is_a_rig_setting():
    """The emulators and their physics are another process (their scheduling is not ours), and
    the ODrive heartbeat timeout comes from the rig file (default 1 s: ten 100 ms heartbeat periods)."""
    import os

    from beambench.acquisition.protocol.schema import OdriveWiring, RigFile, load_rig_file
    from beambench.backends.hardware import DEFAULT_RIG_FILE

    assert RigFile().odrive.heartbeat_timeout_s == load_rig_file(DEFAULT_RIG_FILE).odrive.heartbeat_timeout_s == 1.0
    rig = build_emulated_rig(
        sim_slice(parse_protocol(PROTOCOL)), wiring=RigFile(odrive=OdriveWiring(heartbeat_timeout_s=0.8))
    )
    peers = rig.peers[0]
    try:
        assert peers.pid != os.getpid() and os.path.exists(f"/proc/{peers.pid}")
        assert rig.motor.heartbeat_timeout_s == 0.8
    finally:
        rig.close()
    assert peers.report is not None  # said what it injected
    assert not os.path.exists(f"/proc/{peers.pid}")  # and its process ended (and was reaped)
