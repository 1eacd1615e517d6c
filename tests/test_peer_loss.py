"""The emulated rig's peers (Motive, the ODrive, the load-cell board: a process of their own) lost at any moment of
a run's start-up, and the run itself killed by SIGKILL.

- Peers killed 0.3-3 s after they started (handshake, start, arm, first steps): one line naming the loss, exit 1
  (EXIT_FAULT), no traceback, and never the misleading "errors persist after Clear_Errors" of a stale heartbeat.
- The run killed by SIGKILL (nothing can catch it): the emulated ODrive, like a real one, runs on unfed until its
  own watchdog idles the axis, within ``watchdog_timeout_s`` (0.5 s) of the host's last frame.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from beambench.sinks.session_file.reader import read_session
from conftest import pause, wait_until

ENDLESS = """
name: endless
sweep: {start: 2, stop: 40, step: 0.19}
settle_s: 0.2
record_s: 0.3
sim: {seed: 5}
"""
WATCHDOG_TIMEOUT_S = 0.5  # the emulated ODrive's axis.config.watchdog_timeout


def _env() -> dict[str, str]:
    src = str(Path(__file__).resolve().parents[1] / "src")
    return dict(os.environ, PYTHONUNBUFFERED="1", PYTHONPATH=os.environ.get("PYTHONPATH") or src)


def _peers_pid(pid: int) -> int | None:
    """The run's emulated-peers process (``python -c "from beambench.backends.emulated import _peer_entry…"``)."""
    for task in Path(f"/proc/{pid}/task").iterdir():
        with open(task / "children") as fh:
            for child in fh.read().split():
                try:
                    cmdline = Path(f"/proc/{child}/cmdline").read_bytes()
                except OSError:
                    continue
                if b"_peer_entry" in cmdline:
                    return int(child)
    return None


def _start(tmp_path: Path, name: str) -> tuple[subprocess.Popen, Path]:
    proto = tmp_path / "endless.yaml"
    proto.write_text(ENDLESS)
    argv = ["run", str(proto), "-b", "emulated", "--out", str(tmp_path), "--name", name, "--rerun", "off"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "beambench.cli", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=_env(),
        start_new_session=True,
    )
    return proc, tmp_path / f"{name}.h5"


pytestmark = pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="finds the peers' process in /proc")


@pytest.mark.slow
@pytest.mark.parametrize(  # early, mid and late in the start-up by default; the soak tier (--soak, CI) adds three more
    "delay",
    [
        0.3,
        pytest.param(0.8, marks=pytest.mark.soak),
        1.3,
        *(pytest.param(d, marks=pytest.mark.soak) for d in (1.5, 2.0)),
        3.0,
    ],
)
def test_peers_killed_during_start_up_are_one_line_and_exit_1(tmp_path, delay):
    proc, path = _start(tmp_path, "p")
    try:

        def peers_started() -> int | None:
            assert proc.poll() is None, proc.communicate()[1].decode()[-2000:]
            return _peers_pid(proc.pid)

        peers = wait_until(peers_started, 60, "the peers' process")
        # no GLFW version probe (a `python -c` child of the peers, which mujoco's import starts unless MUJOCO_GL
        # says otherwise): killed with the peers, it printed a BrokenPipeError traceback on the run's stderr
        assert b"MUJOCO_GL=disable" in Path(f"/proc/{peers}/environ").read_bytes().split(b"\0")
        pause(delay, "the moment in the start-up the peers are killed at")
        os.kill(peers, signal.SIGKILL)
        _, err_b = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = err_b.decode(errors="replace")
    assert proc.returncode == 1, f"exit {proc.returncode}: {err[-3000:]}"
    assert "Traceback" not in err and "Exception ignored" not in err, err[-3000:]
    said = [line for line in err.replace("\r", "\n").splitlines() if "beambench:" in line or "warning" in line]
    assert len(said) == 1, said
    assert "errors persist" not in said[0], said
    assert re.search(r"lost|gone|killed|ended|no heartbeat|silent|no .* for|port .* failed|did not start", said[0]), (
        said
    )
    if path.exists() and "no session written" not in said[0]:
        s = read_session(path)  # the ODrive is gone, so no telemetry shows the stop: the idle command is logged
        assert "idle" in list(s.events["kind"]), list(s.events["kind"])
        assert s.events["kind"].iloc[-1] in ("fault", "error"), list(s.events["kind"])


def _stepping(path: Path) -> bool:
    try:
        return len(read_session(path).steps) >= 3
    except OSError:  # not created yet, or still being set up
        return False


@pytest.mark.slow
def test_a_run_killed_by_sigkill_leaves_the_emulated_odrive_to_its_watchdog(tmp_path):
    proc, path = _start(tmp_path, "k")
    try:

        def stepping() -> bool:  # the motor turning
            assert proc.poll() is None, proc.communicate()[1].decode()[-2000:]
            return _stepping(path)

        wait_until(stepping, 120, "the run to step", 0.1)
        peers = _peers_pid(proc.pid)
        assert peers is not None
        os.kill(proc.pid, signal.SIGKILL)
        _, err_b = proc.communicate(timeout=30)  # the peers inherited stderr: it closes when they are done
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = err_b.decode(errors="replace")
    assert proc.returncode == -signal.SIGKILL
    found = re.search(r"emulated ODrive: its watchdog idled the axis ([0-9.]+) s after the host was lost", err)
    assert found, err[-2000:]
    assert float(found.group(1)) <= WATCHDOG_TIMEOUT_S + 0.25, found.group(0)
    assert "0x800" in err  # AxisError.WATCHDOG_TIMER_EXPIRED


def test_no_command_imports_glfw():
    """Importing mujoco imports GLFW unless ``MUJOCO_GL`` says otherwise, and GLFW's import starts a ``python -c``
    probe of its library version (a process start per command; killed with its parent, a traceback on the run's
    stderr). The CLI sets ``MUJOCO_GL=disable`` before anything imports mujoco, unless the user set it."""
    env = {k: v for k, v in _env().items() if k != "MUJOCO_GL"}
    code = (
        "import os, sys, beambench.cli, beambench.backends.emulated, beambench.session.run, mujoco\n"
        "print(os.environ['MUJOCO_GL'], 'glfw' in sys.modules)"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["disable", "False"], res.stdout
    mine = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={**env, "MUJOCO_GL": "egl"}, timeout=120
    )
    assert mine.stdout.split()[0] == "egl", (mine.stdout, mine.stderr)  # the user's choice wins
