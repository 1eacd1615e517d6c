"""A flood of junk datagrams from another program on this machine (not spoofed: its own address and port) to both
UDP ports of an emulated run — the NatNet client's socket and the host's end of the loopback CAN bus — while the
motor is armed: the watchdog feed goes on (the emulated ODrive's watchdog never expires), the run completes or
stops with a line naming the flood, the idle is on the CAN bus, and every datagram is in the session's counts,
refused by sender or dropped by the kernel unread."""

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
from beambench.devices.odrive.cansimple import AxisError, AxisState
from beambench.session.slices import sim_slice
from beambench.sinks.session_file.reader import read_session
from beambench.sinks.session_file.writer import SessionWriter, append_general
from conftest import last_requested_state, wait_until

PROTOCOL = """
name: flood
sweep: {frequencies: [6]}
settle_s: 0.4
record_s: 3.0
sim: {seed: 5}
monitors: {mocap_lost_s: null}
"""
N = 1000  # datagrams to each port, as fast as one socket sends them


def _flood(rig, stop: threading.Event, sent: dict) -> None:
    """Once the motor is in closed loop: N datagrams of random junk (1 to 1400 bytes) to each port."""
    motor = rig.motor
    wait_until(
        lambda: (
            stop.is_set()
            or (motor.heartbeat is not None and motor.heartbeat.axis_state == AxisState.CLOSED_LOOP_CONTROL)
        ),
        60,
        "closed loop",
    )
    targets = {"mocap": rig.mocap.client.receive_address, "motor": ("127.0.0.1", motor.link.bus.port)}
    rng = np.random.default_rng(7)
    junk = [rng.bytes(int(n)) for n in rng.integers(1, 1400, 64)]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        sent["from"] = "{}:{}".format(*s.getsockname())
        for i in range(N):
            for stream, target in targets.items():
                s.sendto(junk[i % len(junk)], target)
                sent[stream] = sent.get(stream, 0) + 1


@pytest.fixture(scope="module")
def flooded(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("flood")
    protocol = parse_protocol(PROTOCOL)
    can_log = tmp / "flood.asc"
    rig = build_emulated_rig(sim_slice(protocol), can_log=can_log)
    rig.open()
    path = tmp / "flood.h5"
    writer = SessionWriter(path, {"protocol": PROTOCOL, "backend": "emulated"})
    hub = Hub([writer], critical=(writer,))
    hub.open([s.describe() for s in rig.streams])
    stop, sent = threading.Event(), {}
    flooder = threading.Thread(target=_flood, args=(rig, stop, sent), daemon=True)
    flooder.start()
    try:
        result = Runner(rig, hub, plan(protocol), motor_limits(protocol), poll_s=0.1).run()
    finally:
        stop.set()
        flooder.join(30)
    append_general(path, rig.after_run())  # the drivers' counters into /general/devices, as a run does
    return result, rig, sent, can_log, read_session(path)


def test_a_flood_does_not_starve_the_watchdog_feed(flooded):
    result, rig, sent, can_log, _s = flooded
    assert sent.get("mocap") == sent.get("motor") == N, sent
    if result.status != "completed":  # a flood may stop a run, but then the line says so (not the watchdog)
        assert result.status == "fault" and "during a flood" in result.message, result.message
    assert "WATCHDOG" not in result.message, result.message
    odrive = rig.peers[0].odrive.snapshot()
    assert not odrive["axis_error"] & AxisError.WATCHDOG_TIMER_EXPIRED, odrive
    assert odrive["state"] == AxisState.IDLE
    assert last_requested_state(can_log) == AxisState.IDLE  # the idle, decoded from the bus


def test_every_flooded_datagram_is_counted_and_the_flood_is_named(flooded):
    result, _rig, sent, _can_log, s = flooded
    devices = s.general["devices"]
    for stream in ("mocap", "motor"):
        counts = devices[stream]
        forged, kernel = int(counts["forged"]), int(counts["kernel_dropped"])
        # every junk datagram was read and refused, or dropped by the kernel unread; the kernel's drops may also
        # hold the device's own frames the flood pushed out (mocap: those are gaps in the frame numbers)
        assert forged <= N <= forged + kernel, (stream, counts)
        if stream == "mocap":
            assert forged + kernel <= N + int(counts["dropped"]) + 5, counts
        assert f"{forged} datagrams from {sent['from']} dropped" in counts["flood"], counts["flood"]
    floods = [m for k, m in zip(s.events["kind"], s.events["message"], strict=True) if k == "flood"]
    assert sorted(m.split(":")[0] for m in floods) == ["mocap", "motor"], floods
    assert all(sent["from"] in m for m in floods), floods
    assert result.status != "completed" or len([w for w in result.warnings if "flood" in w]) == 2, result.warnings
