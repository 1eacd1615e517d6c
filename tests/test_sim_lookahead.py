"""The sim rig computing the runner's announced schedule ahead (beambench.backends.lookahead): the same data as stepping
on demand, a clean fallback when the run leaves the schedule, and the walker's sweep cut into parallel segments."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from beambench.acquisition.capabilities import MotorLimits
from beambench.acquisition.protocol.schema import parse_protocol
from beambench.acquisition.runner import record_polls, wait_polls
from beambench.backends.lookahead import Lookahead, cut_points, script
from beambench.backends.sim import SimRig
from beambench.cli import app
from beambench.session.slices import sim_slice
from beambench.sinks.session_file.reader import read_session
from conftest import wait_until

WALKER = """
name: walk
rig: walker
sweep: {frequencies: [%s]}
settle_s: %s
record_s: %s
amplitude_mm: 2.0
limits: {max_frequency_hz: 80, max_current_a: 6}
sim: {model: prb3, seed: 2, segments: %d}
"""


def walker(freqs: str = "40, 50", settle: float = 0.3, record: float = 0.4, segments: int = 1):
    return parse_protocol(WALKER % (freqs, settle, record, segments))


def drive(rig: SimRig, calls: list[tuple[float, list[float]]], announce: list[tuple[float, list[float]]] | None):
    """Drive ``rig`` as the runner does (arm, then per step a command and its waits), announcing ``announce``;
    returns every stream's samples."""
    rig.open()
    rig.motor.arm(MotorLimits(max_frequency_hz=80, max_current_a=6, amplitude_mm=2.0))
    if announce is not None:
        rig.anticipate(announce)
    got: dict[str, list] = {s.name: [] for s in rig.streams}
    for hz, waits in calls:
        rig.motor.set_frequency(hz)
        for w in waits:
            rig.clock.wait(w)
            for s in rig.streams:
                got[s.name].append(s.read())
    rig.close()
    return {
        name: {k: np.concatenate([b.columns[k] for b in batches]) for k in batches[0].columns}
        | {"t": np.concatenate([b.device_time for b in batches])}
        for name, batches in got.items()
    }


def same(a, b) -> None:
    assert a.keys() == b.keys()
    for name in a:
        for k in a[name]:
            np.testing.assert_array_equal(a[name][k], b[name][k], err_msg=f"{name}/{k}")


def test_polls_of_a_window():
    assert wait_polls(1.0, 0.5) == [0.5, 0.5]
    assert wait_polls(1.2, 0.5) == pytest.approx([0.4, 0.4, 0.4])
    assert wait_polls(0.0, 0.5) == []
    assert record_polls(1.2, 0.5) == pytest.approx([0.5, 0.5, 0.2])


def test_script_and_cuts_follow_the_clock():
    calls = script([(5.0, [0.5, 0.7]), (6.0, [0.2])], now_ns=1000, max_chunk_ns=500_000_000)
    assert calls == [
        ("cmd", 1000, 5.0),
        ("adv", 500_001_000, 0.0),
        ("adv", 1_000_001_000, 0.0),
        ("adv", 1_200_001_000, 0.0),  # a 0.7 s wait in chunks of at most 0.5 s, as SimClock.wait
        ("cmd", 1_200_001_000, 6.0),
        ("adv", 1_400_001_000, 0.0),
    ]
    ten = script([(float(f), [1.0, 2.0]) for f in range(10)], 0, 500_000_000)
    (cut,) = cut_points(ten, 2, presettle_s=4.0)
    # balanced at (30 + 4) / 2 = 17 s (the later part also pre-settles 4 s): the nearest step command is at 18 s
    assert ten[cut][0] == "cmd" and ten[cut][1] == 18_000_000_000
    assert cut_points(ten, 1, 4.0) == [] and cut_points(ten[:3], 2, 4.0) == []


def test_lookahead_gives_the_data_of_stepping_on_demand():
    plan = [(40.0, [0.3, 0.25, 0.25]), (50.0, [0.3, 0.4])]
    ahead = drive(SimRig(sim_slice(walker())), plan, announce=plan)
    on_demand = drive(SimRig(sim_slice(walker()), prefetch=False), plan, announce=None)
    same(ahead, on_demand)
    assert len(ahead["mocap"]["t"]) > 500


def test_a_run_that_leaves_the_schedule_continues_from_where_it_left():
    announced = [(40.0, [0.3, 0.3]), (50.0, [0.3, 0.3]), (60.0, [0.3])]
    actual = [(40.0, [0.3, 0.3]), (50.0, [0.3, 0.1, 0.2]), (70.0, [0.3])]  # a shorter poll, then another frequency
    ahead = drive(SimRig(sim_slice(walker("40, 50, 60"))), actual, announce=announced)
    on_demand = drive(SimRig(sim_slice(walker("40, 50, 60")), prefetch=False), actual, announce=None)
    same(ahead, on_demand)


def test_segments_are_refused_for_other_rigs(tmp_path):
    proto = tmp_path / "r.yaml"
    proto.write_text(
        "name: r\nrig: release\nsweep: {frequencies: [0]}\nsettle_s: 0.1\nrecord_s: 0.1\nrelease: {load_g: 200}\n"
        "limits: {max_frequency_hz: 1, max_current_a: 10, max_amplitude_mm: 3}\nsim: {model: prb3, segments: 2}\n"
    )
    res = CliRunner().invoke(app, ["run", str(proto), "--out", str(tmp_path), "--rerun", "off"])
    assert res.exit_code == 2
    assert "sim.segments" in res.output and "contact or walker only" in res.output


CONTACT = """
name: c
rig: contact
sweep: {frequencies: [%s]}
settle_s: 0.2
record_s: 0.3
amplitude_mm: 2.0
limits: {max_frequency_hz: 40, max_current_a: 10}
sim: {model: rod5g, params: physical, noise: false, segments: 2}
"""


def contact_script(freqs: str) -> tuple[object, list, list]:
    """A contact protocol's scene (the shipped twin), its script of scene calls and the planned cut."""
    from beambench.backends.sim import build_scene

    sim = sim_slice(parse_protocol(CONTACT % freqs))
    scene = build_scene(sim)
    plan = [(float(f), [0.2, 0.3]) for f in freqs.split(",")]
    calls = script(plan, 0, 500_000_000)
    return sim, scene, calls


def take_all(look: Lookahead) -> list:
    rows = []
    for kind, t_ns, hz in look.calls:
        assert look.expects(kind, t_ns, hz)
        rows.append(look.take(rows[-1] if rows and rows[-1] is not None else None))
    look.stop()
    return rows


def test_a_contact_cut_refused_at_every_step_runs_in_one_piece():
    from beambench.backends.sim import build_scene

    sim, scene, calls = contact_script("30, 31, 32, 33")
    cuts = cut_points(calls, 2, 0.5)
    look = Lookahead(scene, calls, cuts, [build_scene(sim)], presettle_s=0.5, walk_axis=None, agree=lambda *_: False)
    rows = take_all(look)
    _, plain_scene, _ = contact_script("30, 31, 32, 33")
    plain = []
    for kind, t_ns, hz in calls:
        if kind == "cmd":
            plain_scene.set_frequency(hz)
        plain.append(None if kind == "cmd" else plain_scene.advance_to(t_ns * 1e-9))
    assert look.cut_times_ns == [] and look.checks[0]["cut_s"] is None  # every step compared, none agreed
    later = [hz for i, (kind, _, hz) in enumerate(calls) if kind == "cmd" and i >= cuts[0]]
    assert look.checks[0]["steps_compared_hz"] == later and len(later) >= 2
    for a, b in zip(rows, plain):
        assert (a is None) == (b is None)
        if a is not None:  # the carried state all the way: the same rows as one piece, bit for bit
            np.testing.assert_array_equal(a.channels["force_nt"], b.channels["force_nt"])


def test_a_contact_cut_moves_to_the_step_after_the_first_that_agrees():
    from beambench.backends.sim import build_scene

    sim, scene, calls = contact_script("30, 31, 32, 33, 34, 35")
    cuts = cut_points(calls, 2, 0.5)
    seen: list[float] = []

    def second_agrees(a, b, hz):  # refuses the planned cut's step, accepts the next one
        seen.append(hz)
        return len(seen) > 1

    look = Lookahead(scene, calls, cuts, [build_scene(sim)], presettle_s=0.5, walk_axis=None, agree=second_agrees)
    rows = take_all(look)
    cmds = [i for i, c in enumerate(calls) if c[0] == "cmd"]
    moved = cmds[cmds.index(cuts[0]) + 2]  # two steps compared: the caller switches at the command after them
    assert look.cut_times_ns == [calls[moved][1]]
    assert seen == [calls[cuts[0]][2], calls[cuts[0]][2] + 1]
    theta = np.concatenate([r.channels["theta"] for r in rows if r is not None])
    x = np.concatenate([r.channels["markers"][:, 0, 0] for r in rows if r is not None])
    np.testing.assert_allclose(x, 0.002 * np.sin(theta), atol=2e-5)  # stage and crank agree across the cut
    assert np.all(np.diff(theta) > -np.pi)  # the motor angle continues by whole turns, never back


@pytest.fixture(scope="module")
def segmented(tmp_path_factory):
    out = tmp_path_factory.mktemp("seg")
    proto = out / "walk.yaml"
    proto.write_text(WALKER % ("60, 61, 62, 63", 0.5, 0.5, 2))
    res = CliRunner().invoke(app, ["run", str(proto), "--out", str(out), "--name", "w", "--rerun", "off"])
    assert res.exit_code == 0, res.output
    return read_session(out / "w.h5")


def test_a_segmented_sweep_takes_every_announced_call_and_records_the_cut(segmented):
    s = segmented
    seg = s.general["sim_segments"]
    assert int(seg["segments"]) == 2
    assert int(seg["calls_taken"]) == int(seg["calls_planned"])  # the runner did exactly what it announced
    cut_ns = round(seg["cut_times_s"][0] * 1e9)
    starts = list(s.steps["t_start_ns"])
    assert cut_ns in starts[1:]  # cut at a step's command, in its settle window
    assert list(s.steps["status"]) == ["done"] * 4


def test_a_segmented_sweep_walks_on_without_a_jump_at_the_cut(segmented):
    s = segmented
    seg = s.general["sim_segments"]
    cut = float(seg["cut_times_s"][0])
    mocap = s.streams["mocap"]
    t = np.asarray(mocap.device_time, float)
    body_x = np.asarray(mocap.columns["data"], float)[:, 0, 0]
    step = np.abs(np.diff(body_x))
    k = int(np.searchsorted(t, cut))
    # the later segment walked ~0.5 m in its pre-settle: stitched, the cut is no bigger than the gait's own jitter
    assert step[k - 2 : k + 2].max() < 3 * np.percentile(step, 99)
    assert body_x[-1] - body_x[0] > 0.3  # it walked forward the whole time (~150 mm/s at 60 Hz)
    motor = s.streams["motor"]
    pos = np.asarray(motor.columns["position"], float)
    assert np.all(np.diff(pos) > 0) and np.diff(pos).max() < 1.0  # the motor angle continues across the cut (turns)


def test_progress_counts_the_work_of_every_parallel_segment():
    """A sweep cut into two segments: before the runner takes anything, the rig reports what both workers computed
    (every step, all the rig time), so progress does not sit at the first segment's share and then jump to the end."""
    rig = SimRig(sim_slice(walker("40, 45, 50, 55", 0.3, 0.4, segments=2)))
    rig.open()
    rig.motor.arm(MotorLimits(max_frequency_hz=80, max_current_a=6, amplitude_mm=2.0))
    try:
        assert rig.computed_ahead() is None  # nothing announced: nothing computed ahead
        rig.anticipate([(hz, [0.3, 0.4]) for hz in (40, 45, 50, 55)])
        wait_until(lambda: (rig.computed_ahead() or (0.0, 0))[1] >= 4, 120, "all four steps computed ahead", 0.02)
        seconds, steps = rig.computed_ahead()  # type: ignore[misc]
        assert steps == 4 and seconds == pytest.approx(4 * 0.7)
        assert rig.clock.now_ns() == 0  # the runner has taken none of it
    finally:
        rig.close()
