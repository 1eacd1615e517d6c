"""The motor's exit paths under a host that stalls, runs out of memory or loses a sink: the motor is idled and
the run says what happened in one line (docs/safety.md, "Motor idle" and "Sinks")."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from beambench.sinks.session_file.reader import read_session
from conftest import armed_for, pause, tmpfs, wait_until

SHORT = """
name: short
sweep: {start: 2, stop: 10, step: 2}
settle_s: 1.0
record_s: 1.0
sim: {seed: 5}
"""


def _env() -> dict[str, str]:
    src = str(Path(__file__).resolve().parents[1] / "src")
    return dict(os.environ, PYTHONUNBUFFERED="1", PYTHONPATH=os.environ.get("PYTHONPATH") or src)


def _start(tmp_path: Path, *extra: str) -> subprocess.Popen:
    proto = tmp_path / "short.yaml"
    proto.write_text(SHORT)
    argv = ["run", str(proto), "-b", "emulated", "--out", str(tmp_path), "--name", "s", "--rerun", "off", *extra]
    return subprocess.Popen(
        [sys.executable, "-m", "beambench.cli", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=_env(),
        start_new_session=True,
    )


def _wait_armed(proc: subprocess.Popen, can_log: Path, for_s: float = 0.5, timeout: float = 120.0) -> None:
    """Until the CAN log shows the closed-loop request and ``for_s`` of traffic after it (the motor is armed)."""

    def armed() -> bool:
        assert proc.poll() is None, proc.communicate()[1].decode(errors="replace")[-2000:]
        return armed_for(can_log, for_s)

    wait_until(armed, timeout, "the run to arm the motor", 0.05)


def _said(err: bytes) -> list[str]:
    text = err.decode(errors="replace")
    assert "Traceback" not in text, text[-3000:]
    return [line for line in text.replace("\r", "\n").splitlines() if line.startswith("beambench:")]


@pytest.mark.slow
@pytest.mark.parametrize(
    "stall_s", [2.0, pytest.param(0.8, marks=pytest.mark.soak), pytest.param(5.0, marks=pytest.mark.soak)]
)
def test_a_stalled_host_is_said_to_be_the_host_not_the_odrive(tmp_path, stall_s):
    """SIGSTOP of the armed run for longer than the heartbeat timeout: the ODrive's watchdog idles the axis; the
    run ends as a fault that names the host's stall (its length), not a lost ODrive heartbeat."""
    can_log = tmp_path / "s.asc"
    proc = _start(tmp_path, "--can-log", str(can_log))
    try:
        _wait_armed(proc, can_log)
        proc.send_signal(signal.SIGSTOP)
        pause(stall_s, "the host's stall: its length is the input")
        proc.send_signal(signal.SIGCONT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    said = _said(err)
    assert proc.returncode == 1 and len(said) == 1, (proc.returncode, said)
    assert "heartbeat lost" not in said[0], said
    stalled = re.search(r"the host stalled for (\d+) ms", said[0])
    assert stalled and int(stalled.group(1)) >= 500, said  # > the 0.5 s watchdog timeout; of the order of the stall
    assert int(stalled.group(1)) <= stall_s * 1e3 + 5000, said
    s = read_session(tmp_path / "s.h5")  # the stall left a session that reads (no stamp goes back in time)
    assert s.streams["motor"].columns["axis_state"][-1] == 1  # AXIS_STATE_IDLE
    assert (np.diff(s.streams["mocap"].host_time_ns) >= 0).all()


def _vm_size(pid: int) -> int:
    status = Path(f"/proc/{pid}/status").read_text()
    found = re.search(r"VmSize:\s+(\d+) kB", status)
    assert found, status
    return int(found.group(1)) * 1024


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads the run's size in /proc")
@pytest.mark.parametrize(
    "headroom_mb", [0, pytest.param(4, marks=pytest.mark.soak), pytest.param(32, marks=pytest.mark.soak)]
)
def test_memory_exhausted_mid_run_idles_the_motor_confirmed_in_one_line(tmp_path, headroom_mb):
    """RLIMIT_AS set on the armed run at its size (+ headroom): the allocation that fails ends the run with one
    line, no traceback; the idle frames (packed ahead) still go out and the ODrive confirms AXIS_STATE_IDLE."""
    resource = pytest.importorskip("resource")
    can_log = tmp_path / "s.asc"
    proc = _start(tmp_path, "--can-log", str(can_log))
    try:
        _wait_armed(proc, can_log)
        limit = _vm_size(proc.pid) + headroom_mb * 2**20
        resource.prlimit(proc.pid, resource.RLIMIT_AS, (limit, resource.RLIM_INFINITY))
        _, err = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    said = _said(err)
    assert proc.returncode in (0, 1), (proc.returncode, said)
    assert len(said) == (proc.returncode != 0), said
    s = read_session(tmp_path / "s.h5")
    idle = [m for k, m in zip(s.events["kind"], s.events["message"]) if k == "idle"]
    assert idle == ["motor idle (ODrive node 0 confirms AXIS_STATE_IDLE)"], idle
    if said:
        assert "confirms AXIS_STATE_IDLE" in said[0], said
    assert s.streams["motor"].columns["axis_state"][-1] == 1  # AXIS_STATE_IDLE, as the device reported it


@pytest.mark.parametrize("kind", ["device", "existing", "under-a-file"])
def test_a_can_log_that_cannot_be_a_new_file_is_bad_input_before_anything_moves(tmp_path, kind):
    """``--can-log`` naming a device (a link to /dev/full), an existing file (never truncated) or a path under
    a file: one line naming --can-log, exit 2, no session, and the existing file untouched."""
    log = tmp_path / "bus.asc"
    if kind == "device":
        log.symlink_to("/dev/full")
    elif kind == "existing":
        log.write_text("keep me\n")
    else:
        (tmp_path / "afile").write_text("")
        log = tmp_path / "afile" / "bus.asc"
    proc = _start(tmp_path, "--can-log", str(log))
    _, err = proc.communicate(timeout=120)
    said = _said(err)
    assert proc.returncode == 2 and len(said) == 1 and "--can-log" in said[0], (proc.returncode, said)
    assert not (tmp_path / "s.h5").exists()
    if kind == "existing":
        assert log.read_text() == "keep me\n"
    if kind == "device":
        assert "not a regular file" in said[0], said  # not "a folder"


@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 KiB tmpfs at ``tmp_path/disk`` (root only), unmounted after the test."""
    with tmpfs(tmp_path / "disk", "64k") as disk:
        yield disk


@pytest.mark.slow
def test_a_can_log_on_a_full_disk_fails_the_run_as_a_sink_motor_idle_first(tmp_path, tiny_disk):
    """The CAN log fills its disk mid-run: one line naming the log and the full disk, exit 4, the motor idle
    (confirmed by the ODrive) before the session closes."""
    proc = _start(tmp_path, "--can-log", str(tiny_disk / "bus.asc"))
    _, err = proc.communicate(timeout=180)
    said = _said(err)
    assert proc.returncode == 4 and len(said) == 1, (proc.returncode, said)
    assert "CAN log" in said[0] and "No space left" in said[0], said
    s = read_session(tmp_path / "s.h5")
    idle = [m for k, m in zip(s.events["kind"], s.events["message"]) if k == "idle"]
    assert idle == ["motor idle (ODrive node 0 confirms AXIS_STATE_IDLE)"], idle
    assert s.streams["motor"].columns["axis_state"][-1] == 1


def test_a_can_log_in_a_read_only_folder_is_bad_input_before_anything_moves(tmp_path):
    """A read-only filesystem (refused even to root): one line naming --can-log, exit 2, no session."""
    ro = tmp_path / "ro"
    ro.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)], capture_output=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a read-only tmpfs here: {res.stderr.decode(errors='replace').strip()[:120]}")
    try:
        proc = _start(tmp_path, "--can-log", str(ro / "bus.asc"))
        _, err = proc.communicate(timeout=120)
    finally:
        subprocess.run(["umount", "-l", str(ro)], capture_output=True, timeout=10)
    said = _said(err)
    assert proc.returncode == 2 and len(said) == 1 and "--can-log" in said[0] and "read-only" in said[0], said
    assert not (tmp_path / "s.h5").exists()


@pytest.mark.skipif(sys.platform != "linux", reason="RLIMIT_AS through preexec_fn: Linux")
@pytest.mark.parametrize("limit_mb", [300, 350, 450])
def test_the_whole_command_under_a_memory_limit_ends_in_one_line(tmp_path, limit_mb):
    """``prlimit --as`` on the whole command: whatever runs out first (an extension's import, MuJoCo's model
    compile, a thread start) ends it with one line and exit 1, never a traceback; enough memory runs it (exit 0)."""
    import resource

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit_mb << 20, limit_mb << 20))

    env = dict(_env(), BEAMBENCH_USER_DIR=str(tmp_path / "user"), OPENBLAS_NUM_THREADS="1")
    argv = ["run", "contact_sweep", "--rerun", "off", "--out", str(tmp_path / "out")]
    res = subprocess.run(
        [sys.executable, "-m", "beambench.cli", *argv], env=env, preexec_fn=limit, capture_output=True, timeout=300
    )
    err = res.stderr.decode(errors="replace")
    assert "Traceback" not in err, err[-3000:]
    said = [ln for ln in err.splitlines() if ln.strip() and not re.match(r"^\d\d:\d\d:\d\d ", ln)]
    assert res.returncode in (0, 1), (res.returncode, said)
    if res.returncode == 1:  # OpenBLAS that cannot allocate its buffers ends the process itself, in its own line
        assert len(said) == 1 and said[0].startswith(("beambench:", "OpenBLAS error:")), said
