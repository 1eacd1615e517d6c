"""Monitors: a real mocap outage (Motive stops sending over UDP) pauses the record window, which then runs
longer so the step still holds its full window of good frames; an outage longer than max_pause_s stops the
run as a fault, motor idle first, everything recorded saved."""

from __future__ import annotations

import numpy as np

from beambench.acquisition.batch import Batch
from beambench.acquisition.hub import Hub
from beambench.acquisition.monitors import MocapLost, StreamSilent, build_monitors
from beambench.acquisition.protocol.plan import motor_limits, plan
from beambench.acquisition.protocol.schema import parse_protocol
from beambench.acquisition.runner import Runner
from beambench.backends.emulated import build_emulated_rig
from beambench.devices.odrive.cansimple import AxisState
from beambench.session.slices import sim_slice
from beambench.sinks.session_file.reader import read_session
from beambench.sinks.session_file.writer import SessionWriter

MS = 1_000_000


def _mocap(t_ms: list[float], occluded: list[bool] | None = None) -> Batch:
    n = len(t_ms)
    occ = np.zeros((n, 3), bool) if occluded is None else np.array([[o, False, False] for o in occluded])
    return Batch(
        "mocap",
        np.array(t_ms, float).astype(np.int64) * MS,
        np.zeros(n),
        {"data": np.zeros((n, 3, 3)), "frame": np.arange(n), "occluded": occ},
    )


def test_mocap_lost_needs_a_complete_frame_within_the_timeout():
    m = MocapLost(0.25)
    assert m.problem(0) is None  # watching starts: a grace period of one timeout
    assert m.problem(300 * MS) == ("mocap lost: no frame for 0.30 s", 0)
    m.write(_mocap([290, 295, 299]))
    assert m.problem(300 * MS) is None
    m.write(_mocap([400, 500, 600], occluded=[True, True, True]))  # frames arrive, a marker is hidden
    p = m.problem(601 * MS)
    assert "hidden" in p.reason and p.since_ns == 299 * MS  # bad since the last complete frame
    m.write(_mocap([700], occluded=[False]))
    assert m.problem(701 * MS) is None
    m.write(Batch("loadcell", np.array([2000 * MS]), np.zeros(1), {}))  # other streams do not count
    assert "no frame" in m.problem(2000 * MS).reason


def test_stream_silent_watches_one_stream_with_its_own_timeout():
    m = StreamSilent("loadcell", 0.5)
    assert m.problem(0) is None  # grace period from the first look
    m.write(Batch("loadcell", np.array([100 * MS]), np.zeros(1), {}))
    assert m.problem(550 * MS) is None
    m.write(_mocap([900]))  # another stream does not count
    p = m.problem(700 * MS)
    assert p is not None and p.reason == "loadcell: no sample for 0.60 s" and p.since_ns == 100 * MS
    on = parse_protocol("sweep: {frequencies: [5]}\n")
    built = build_monitors(on, ["motor", "mocap", "loadcell"], silence_s={"loadcell": 0.5, "absent": 1.0})
    assert [type(b).__name__ for b in built] == ["MocapLost", "StreamSilent"]


def test_protocol_can_switch_the_monitor_off():
    on = parse_protocol("sweep: {frequencies: [5]}\n")
    off = parse_protocol("sweep: {frequencies: [5]}\nmonitors: {mocap_lost_s: null}\n")
    assert len(build_monitors(on, ["motor", "mocap"])) == 1
    assert build_monitors(off, ["motor", "mocap"]) == []


PROTOCOL = (
    "name: mon\nsweep: {frequencies: [10]}\nsettle_s: 0.3\nrecord_s: 1.0\nsim: {seed: 2}\n"
    "monitors: {mocap_lost_s: 0.1, max_pause_s: %g}\n"
)


def _run(tmp_path, outage_s: float, max_pause_s: float):
    protocol = parse_protocol(PROTOCOL % max_pause_s)
    rig = build_emulated_rig(sim_slice(protocol))
    rig.open()
    path = tmp_path / "mon.h5"
    monitors = build_monitors(protocol, [s.describe().name for s in rig.streams])
    writer = SessionWriter(path, {"protocol": "x", "backend": "emulated"})
    hub = Hub([writer, *monitors], critical=(writer,))
    hub.open([s.describe() for s in rig.streams])
    waited = {"s": 0.0, "started": False}

    def on_progress(index: int, freq: float, seconds: float) -> None:
        waited["s"] += seconds
        if not waited["started"] and waited["s"] >= protocol.settle_s + 0.3:  # 0.3 s into the record window
            waited["started"] = True
            rig.peers[0].outage("mocap", outage_s)  # the emulated Motive (own process) sends nothing this long

    runner = Runner(
        rig,
        hub,
        plan(protocol),
        motor_limits(protocol),
        poll_s=0.05,
        on_progress=on_progress,
        monitors=monitors,
        max_pause_s=max_pause_s,
    )
    result = runner.run()
    return result, rig, read_session(path)


def test_an_outage_pauses_the_window_and_the_step_still_gets_its_full_record(tmp_path):
    result, rig, s = _run(tmp_path, outage_s=0.6, max_pause_s=5.0)
    assert result.status == "completed", result.message
    kinds = list(s.events["kind"])
    assert "pause" in kinds and "resume" in kinds and kinds.index("pause") < kinds.index("resume")
    pause = s.events[s.events.kind == "pause"]
    assert "mocap lost" in pause.message.iloc[0]
    step = s.steps.iloc[0]
    window_s = (step.t_end_ns - step.t_settled_ns) * 1e-9
    assert window_s >= 1.0 + 0.5  # the window grew by about the outage
    m = s.streams["mocap"]
    inside = (m.host_time_ns >= step.t_settled_ns) & (m.host_time_ns < step.t_end_ns)
    assert inside.sum() >= 0.99 * 360 * 1.0  # a full second of good frames despite the outage
    gaps = np.diff(m.host_time_ns[inside]) * 1e-9
    assert gaps.max() > 0.5  # and the outage really happened on the wire
    assert len(rig.peers[0].reported["mocap"].dropped_frames) > 0.5 * 360


def test_an_outage_longer_than_max_pause_is_a_fault_that_idles_and_saves(tmp_path):
    result, rig, s = _run(tmp_path, outage_s=10.0, max_pause_s=0.4)
    assert result.status == "fault" and "mocap lost" in result.message
    assert "max_pause_s" in result.message
    kinds = list(s.events["kind"])
    assert [k for k in kinds if k != "devices"][-2:] == ["idle", "fault"] and "pause" in kinds
    assert s.steps.iloc[0].status == "fault"
    assert rig.peers[0].odrive.snapshot()["state"] == AxisState.IDLE
    assert s.streams["motor"].columns["velocity_setpoint"][-1] == 0.0
    assert len(s.streams["mocap"]) > 360 * 0.3  # what was recorded before the outage is in the file
