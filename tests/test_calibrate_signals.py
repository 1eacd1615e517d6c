"""``calibrate sim`` and stop signals, as ``run`` takes them: SIGINT, SIGTERM (and the other stop signals) at any
moment from beambench's first line on — during the imports, the checks, the pool's start or the search — end it with the one
line that says how to resume and its interrupted exit code, never an empty stderr; SIGINT is taken even when the
command was started with it ignored (a shell script's background job); the worker pool is shut down, so Python's
resource tracker finds no leaked semaphore. The default run makes three stops at random moments of the first
12 s; the soak tier more."""

from __future__ import annotations

import contextlib
import os
import random
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from beambench.commands import EXIT_STOPPED
from conftest import holds_for, wait_until
from import_stops import stopped_at_import

ROOT = Path(__file__).resolve().parents[1]
TARGETS = ROOT / "calibration" / "paper_contact_targets.yaml"


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # what a non-interactive shell does to a background job


def _catches_sigterm(pid: int) -> bool:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) >> (signal.SIGTERM - 1) & 1)
    return False


def _wait_for_its_handlers(proc: subprocess.Popen, err: Path) -> None:
    """Until beambench's first line has run (it catches SIGTERM from then on): before, the interpreter is still
    starting, which no program can take a signal in."""

    def handles_sigterm() -> bool:
        assert proc.poll() is None, err.read_text()[-2000:]
        return _catches_sigterm(proc.pid)

    wait_until(handles_sigterm, 60, "beambench to start (catch SIGTERM)", interval_s=0.005)


def _stop_at(tmp_path: Path, sig: signal.Signals, after_s: float, ignored: bool) -> None:
    env = dict(os.environ, PYTHONPATH=os.environ.get("PYTHONPATH") or str(ROOT / "src"), PYTHONUNBUFFERED="1")
    out = tmp_path / f"{sig.name}-{after_s:.2f}"
    cmd = [sys.executable, "-m", "beambench.cli", "calibrate", "sim", "--targets", str(TARGETS), "--quick"]
    cmd += ["--out", str(out), "--workers", "1", "--name", "c"]
    err = tmp_path / f"{out.name}.err"
    with err.open("wb") as f:
        proc = subprocess.Popen(
            cmd, stdout=subprocess.DEVNULL, stderr=f, env=env, preexec_fn=_ignore_sigint if ignored else None
        )
        try:
            _wait_for_its_handlers(proc, err)

            def running() -> bool:
                assert proc.poll() is None, err.read_text()[-2000:]
                return True

            holds_for(running, after_s, "the calibration running until the stop's random moment")
            proc.send_signal(sig)
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=90)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
                pytest.fail(f"{sig.name} after {after_s:.2f} s: still running 90 s later")
    text = err.read_text(errors="replace")
    said = [ln for ln in text.replace("\r", "\n").splitlines() if ln.startswith("beambench:")]
    why = f"{sig.name} after {after_s:.2f} s (SIGINT ignored at start: {ignored}): {text[-2000:]}"
    assert proc.returncode == EXIT_STOPPED, why
    assert len(said) == 1 and "calibration interrupted" in said[0], why
    assert f"to resume, run beambench calibrate sim --targets {TARGETS}" in said[0], why
    assert "Traceback" not in text and "leaked semaphore" not in text and "resource_tracker" not in text, why


CASES = [(signal.SIGINT, False), (signal.SIGINT, True), (signal.SIGTERM, False)]


@pytest.mark.slow
@pytest.mark.parametrize(("sig", "ignored"), CASES, ids=["SIGINT", "SIGINT-ignored-at-start", "SIGTERM"])
def test_a_stop_at_a_random_moment_says_how_to_resume(tmp_path, sig, ignored):
    _stop_at(tmp_path, sig, random.uniform(0.0, 12.0), ignored)


@pytest.mark.soak
@pytest.mark.parametrize("n", range(4))
@pytest.mark.parametrize(("sig", "ignored"), CASES, ids=["SIGINT", "SIGINT-ignored-at-start", "SIGTERM"])
def test_more_stops_at_random_moments(tmp_path, sig, ignored, n):
    _stop_at(tmp_path, sig, random.uniform(0.0, 15.0), ignored)


@pytest.mark.parametrize("via", ["PyRun_String", "Python"])
@pytest.mark.parametrize("package", ["beambench.studies", "mujoco"])
def test_a_stop_inside_the_commands_imports_exits_with_its_code(tmp_path, package, via):
    """SIGINT while ``calibrate sim`` imports its search (its own modules, or MuJoCo, whose init runs Python through
    PyRun_String): the one resume line and the interrupted exit code — CPython remembers a KeyboardInterrupt that
    left PyRun_String as unhandled even when it was caught, and would end ``python -m`` by killing itself with
    SIGINT (returncode -2) after the line."""
    args = ["calibrate", "sim", "--targets", str(TARGETS), "--quick", "--out", str(tmp_path / "o")]
    code, err = stopped_at_import(tmp_path, package, via, [*args, "--workers", "1", "--name", "c"])
    said = [ln for ln in err.splitlines() if ln.startswith("beambench:")]
    assert code == EXIT_STOPPED, err[-2000:]
    assert len(said) == 1 and "calibration interrupted: before its first evaluation" in said[0], err[-2000:]
    assert "Traceback" not in err, err[-2000:]


@pytest.mark.parametrize("via", ["PyRun_String", "Python"])
def test_a_stop_while_the_command_line_imports_ends_other_commands_with_one_line(tmp_path, via):
    """A command that does not take stop signals itself (here ``doctor``) gets a Ctrl-C that came while the command
    line imported as if it had just come: one line and the interrupted exit code, no traceback."""
    code, err = stopped_at_import(tmp_path, "typer", via, ["doctor"])
    said = [ln for ln in err.splitlines() if ln.startswith("beambench:")]
    assert code == EXIT_STOPPED, err[-2000:]
    assert said == ["beambench: aborted"], err[-2000:]
    assert "Traceback" not in err, err[-2000:]
