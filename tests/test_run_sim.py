"""End to end on the sim backend: `beambench run` → HDF5 session + Rerun recording, read back for real."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import rerun.chunk as rc
from typer.testing import CliRunner

from beambench.cli import app
from beambench.sinks.session_file.reader import read_session
from conftest import wait_until

SHORT = """
name: short
rig: contact
sweep: {frequencies: [5, 12, 20]}
settle_s: 0.4
record_s: 0.6
amplitude_mm: 2.0
limits: {max_frequency_hz: 40}
sim: {seed: 3}
"""


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    proto = out / "short.yaml"
    proto.write_text(SHORT)
    res = CliRunner().invoke(app, ["run", str(proto), "--out", str(out), "--name", "s", "--rerun", "save"])
    assert res.exit_code == 0, res.output
    return out, res.stdout


def test_stdout_is_only_the_paths_with_the_session_last(short_run):
    out, stdout = short_run  # the progress bar and notes go to stderr, so S=$(beambench run … | tail -n1) works
    assert stdout.splitlines() == [str(out / "s.rrd"), str(out / "s.h5")]


def test_a_run_without_a_display_writes_no_recording_unless_asked(tmp_path, monkeypatch):
    """Headless, ``run`` without ``--rerun`` writes the session only (an .rrd is twice its size) and says on
    stderr how to see it; stdout is the session path alone."""
    for var in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(var, raising=False)
    proto = tmp_path / "short.yaml"
    proto.write_text(SHORT)
    res = CliRunner().invoke(app, ["run", str(proto), "--out", str(tmp_path), "--name", "s"])
    assert res.exit_code == 0, res.output
    assert res.stdout.splitlines() == [str(tmp_path / "s.h5")]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.h5", "short.yaml"]
    assert "no live view" in res.stderr and "beambench view" in res.stderr and "--rerun save" in res.stderr


def test_session_sample_counts_steps_and_general(short_run):
    out, _ = short_run
    s = read_session(out / "s.h5")
    total_s = 3 * 1.0
    assert abs(len(s.streams["mocap"]) - 360 * total_s) <= 1
    assert abs(len(s.streams["loadcell"]) - 1000 * total_s) <= 1
    assert list(s.steps["frequency_hz"]) == [5.0, 12.0, 20.0]
    assert list(s.steps["status"]) == ["done"] * 3
    assert s.general["protocol"] == SHORT
    assert s.general["backend"] == "sim"
    assert next(iter(s.events["kind"])) == "start" and list(s.events["kind"])[-1] == "stop"
    for st in s.streams.values():  # every sample has both clocks
        assert np.all(np.diff(st.host_time_ns) > 0)
        assert np.all(np.isfinite(st.device_time))


def test_rrd_holds_the_same_sample_counts(short_run):
    out, _ = short_run
    s = read_session(out / "s.h5")
    rows: dict[str, int] = {}
    for chunk in rc.RrdReader(out / "s.rrd").stream():
        if not chunk.is_static:
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    for ch in ("lc0", "lc1", "lc2", "lc3"):
        assert rows[f"/loadcell/{ch}"] == len(s.streams["loadcell"])
    for marker in ("stage", "tip", "foot"):
        assert rows[f"/mocap/{marker}"] == len(s.streams["mocap"])
    assert rows["/motor/velocity"] == len(s.streams["motor"])


def test_rrd_is_written_in_few_large_chunks_with_forces_in_newtons(short_run):
    """Columns are gathered per entity (~2 MiB a chunk), not one chunk per batch: this short run fits in one
    chunk per entity (it came out as one per ~0.5 s batch, 6+ each, before); plate forces are there in N."""
    from beambench.analysis.session_analysis import session_calibration

    out, _ = short_run
    s = read_session(out / "s.h5")
    chunks: dict[str, list] = {}
    for chunk in rc.RrdReader(out / "s.rrd").stream():
        if not chunk.is_static:
            chunks.setdefault(chunk.entity_path, []).append(chunk)
    assert all(len(c) == 1 for c in chunks.values()), {k: len(c) for k, c in chunks.items()}
    force = session_calibration(s.general).force_from_counts(s.streams["loadcell"].columns["data"])
    for j, name in enumerate(("normal", "tangential")):
        batch = chunks[f"/force/{name}"][0].to_record_batch()
        values = np.concatenate([np.asarray(v) for v in batch.column("Scalars:scalars").to_pylist()])
        assert len(values) == len(force)
        np.testing.assert_allclose(values, force[:, j], atol=1e-9)
    counts = s.streams["loadcell"].columns["data"]
    assert np.abs(counts).max() > 100 and np.abs(force).max() < 1  # newtons beside the raw counts


def test_view_never_overwrites_the_rrd_that_run_saved(short_run, tmp_path):
    out, _ = short_run
    before = (out / "s.rrd").read_bytes()
    runner = CliRunner()
    first = runner.invoke(app, ["view", str(out / "s.h5"), "--rerun", "save"])
    second = runner.invoke(app, ["view", str(out / "s.h5"), "--rerun", "save"])
    assert first.exit_code == 0 and second.exit_code == 0, first.output + second.output
    assert first.stdout.strip() == str(out / "s_view.rrd") and second.stdout.strip() == str(out / "s_view_1.rrd")
    assert (out / "s.rrd").read_bytes() == before
    refused = runner.invoke(app, ["view", str(out / "s.h5"), "--rerun", "save", "--out", str(out / "s.rrd")])
    assert refused.exit_code == 2 and "never overwrites" in refused.stderr
    assert (out / "s.rrd").read_bytes() == before


def test_stage_frequency_and_amplitude_match_command(short_run):
    out, _ = short_run
    s = read_session(out / "s.h5")
    m = s.streams["mocap"]
    labels = m.spec.columns["data"].labels
    x = m.columns["data"][:, labels.index("stage"), 0]
    t = (m.host_time_ns - m.host_time_ns[0]) * 1e-9
    for row in s.steps.itertuples():
        t0 = (row.t_settled_ns - m.host_time_ns[0]) * 1e-9
        t1 = (row.t_end_ns - m.host_time_ns[0]) * 1e-9
        sel = (t >= t0) & (t < t1)
        f_meas, amp = _sine_fit(t[sel], x[sel], row.frequency_hz)
        assert abs(f_meas - row.frequency_hz) < 0.1
        assert abs(amp * 1000 - 2.0) / 2.0 < 0.02


def _sine_fit(t, x, f0):
    """Least-squares sine fit; frequency refined over a fine grid around the command."""
    best = (np.inf, f0, 0.0)
    for f in np.linspace(f0 - 0.5, f0 + 0.5, 401):
        a = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t)])
        coef, _res, *_ = np.linalg.lstsq(a, x, rcond=None)
        r = float(np.sum((a @ coef - x) ** 2))
        if r < best[0]:
            best = (r, f, float(np.hypot(coef[0], coef[1])))
    return best[1], best[2]


def test_over_limit_refused_before_anything_moves(tmp_path):
    proto = tmp_path / "over.yaml"
    proto.write_text("sweep: {frequencies: [10, 90]}\nlimits: {max_frequency_hz: 40}\n")
    res = subprocess.run(
        [sys.executable, "-m", "beambench.cli", "run", str(proto), "--out", str(tmp_path), "--rerun", "off"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and "max_frequency_hz" in res.stderr
    assert "Traceback" not in res.stderr
    assert not list(tmp_path.glob("*.h5"))


@pytest.mark.parametrize(
    ("sim", "reason"),
    [
        ("rig: walker\nsim: {model: auto}", "sim.model = 'auto': auto chooses from the measured contact-rig table"),
        ("sim: {model: rod0}", "sim.model = 'rod0': unknown beam model"),
        ("rig: walker\nsim: {plate_gap_mm: 2}", "sim.plate_gap_mm = 2.0: applies to rig: contact only"),
        ("rig: release\nsim: {tolerance_mm: 0.1}", "sim.tolerance_mm = 0.1: applies to rig: contact only"),
    ],
)
def test_sim_options_the_rig_cannot_build_are_one_line(tmp_path, sim, reason):
    proto = tmp_path / "p.yaml"
    proto.write_text(f"sweep: {{frequencies: [5]}}\n{sim}\n")
    res = CliRunner().invoke(app, ["run", str(proto), "--out", str(tmp_path), "--rerun", "off"])
    assert res.exit_code == 2 and reason in res.output and "Traceback" not in res.output
    assert not list(tmp_path.glob("*.h5"))


LONG = """
name: long
sweep: {start: 2, stop: 40, step: 2}
settle_s: 0.5
record_s: 0.5
"""


def _start_long_run(tmp_path: Path) -> tuple[subprocess.Popen, Path]:
    proto = tmp_path / "long.yaml"
    proto.write_text(LONG)
    path = tmp_path / "k.h5"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "beambench.cli",
            "run",
            str(proto),
            "--out",
            str(tmp_path),
            "--name",
            "k",
            "--rerun",
            "off",
            "--realtime",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
    )

    def three_steps() -> bool:
        try:
            return path.exists() and len(read_session(path).steps) >= 3
        except Exception:  # being created, or mid-write
            return False

    try:
        wait_until(three_steps, 60, "the run to record three steps", 0.2)
    except AssertionError:
        proc.kill()
        proc.communicate()
        raise
    return proc, path


def test_sigkill_leaves_a_readable_file(tmp_path):
    proc, path = _start_long_run(tmp_path)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)
    s = read_session(path)  # opens with swmr=True
    n_steps = len(s.steps)
    assert 3 <= n_steps < 20
    mocap, lc = s.streams["mocap"], s.streams["loadcell"]
    # everything flushed is there: at least the completed steps' worth of samples, in order
    done_s = sum(1.0 for st in s.steps.itertuples() if st.status == "done")
    assert len(mocap) >= 360 * done_s - 1 and len(lc) >= 1000 * done_s - 1
    assert np.all(np.diff(lc.columns["seq"]) == 1)
    assert s.events["kind"].iloc[-1] not in ("stop", "interrupted")  # it never got to say goodbye


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_sigint_and_sigterm_close_the_file_and_log_the_interruption(tmp_path, sig):
    proc, path = _start_long_run(tmp_path)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 3, err  # EXIT_STOPPED
    assert b"Traceback" not in err
    with h5py.File(path, "r") as f:  # a normal (non-SWMR) open works only on a cleanly closed file
        assert f["steps"].shape[0] >= 3
    s = read_session(path)
    kinds = list(s.events["kind"])
    assert kinds[-1] == "interrupted" and "idle" in kinds
    assert kinds.index("idle") < len(kinds) - 1
    assert s.steps["status"].iloc[-1] in ("aborted", "done")
    # the motor was idled: the last telemetry rows command zero velocity
    assert s.streams["motor"].columns["velocity_setpoint"][-1] == 0.0


def test_view_replays_a_session_into_an_rrd(short_run, tmp_path):
    out, _ = short_run
    rrd = tmp_path / "replay.rrd"
    res = CliRunner().invoke(app, ["view", str(out / "s.h5"), "--rerun", "save", "--out", str(rrd)])
    assert res.exit_code == 0, res.output
    s = read_session(out / "s.h5")
    rows: dict[str, int] = {}
    for chunk in rc.RrdReader(rrd).stream():
        if not chunk.is_static:
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    assert rows["/loadcell/lc2"] == len(s.streams["loadcell"])
    assert rows["/mocap/tip"] == len(s.streams["mocap"])
    assert rows["/events"] == len(s.events)


def test_view_replays_a_session_written_before_columns_said_they_are_plotted(short_run, tmp_path):
    """Sessions from before the ``plotted`` attribute: their standard streams' panels are fed as they were."""

    out, _ = short_run
    old = tmp_path / "old.h5"
    shutil.copy(out / "s.h5", old)
    with h5py.File(old, "a") as f:
        for group in f["acquisition"].values():
            for ds in group.values():
                ds.attrs.pop("plotted", None)
    rrd = tmp_path / "old.rrd"
    res = CliRunner().invoke(app, ["view", str(old), "--rerun", "save", "--out", str(rrd)])
    assert res.exit_code == 0, res.output
    s = read_session(old)
    assert not any(c.plotted for c in s.streams["mocap"].spec.columns.values())
    rows: dict[str, int] = {}
    for chunk in rc.RrdReader(rrd).stream():
        if not chunk.is_static:
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    assert rows["/motor/velocity"] == rows["/motor/iq_measured"] == len(s.streams["motor"])
    assert rows["/loadcell/lc0"] == len(s.streams["loadcell"])
    assert "/motor/position" not in rows


def test_view_of_a_missing_file_is_one_clear_line(tmp_path):
    res = CliRunner().invoke(app, ["view", str(tmp_path / "nope.h5")])
    assert res.exit_code == 2 and "no such session file" in res.output
