"""Every file input is checked for its kind and size before it is read: a folder, a FIFO (which would
block the read), a device (``/dev/zero`` never ends) or a 2 GB file is one line and exit 2, at once — for the
protocol, the rig file, a sweep file, calibrate's --targets, a session, a NatNet capture, a load-cell calibration.
(A 2 GB --targets was read whole before: 4.3 GB of memory, 10-19 s, then a two-line YAML error.)"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from beambench.cli import app

ROOT = Path(__file__).resolve().parents[1]
PROTOCOL = str(ROOT / "protocols" / "contact_sweep.yaml")


def _big(tmp_path: Path) -> Path:
    """A 2 GB sparse file (costs no disk): its size is what a reader would have to get through."""
    p = tmp_path / "big.yaml"
    with open(p, "wb") as fh:
        fh.truncate(2 * 10**9)
    return p


def _fifo(tmp_path: Path) -> Path:
    p = tmp_path / "pipe.yaml"
    os.mkfifo(p)
    return p


KINDS = {
    "folder": lambda tmp: tmp,
    "fifo": _fifo,
    "device": lambda tmp: Path("/dev/zero"),
    "2GB": _big,
}

COMMANDS = {
    "protocol": lambda f: ["run", f, "--dry-run"],
    "rig file": lambda f: ["run", PROTOCOL, "-b", "emulated", "--rig", f, "--rerun", "off", "--dry-run"],
    "sweep file": lambda f: ["sweep", f, "--dry-run"],
    "targets": lambda f: ["calibrate", "sim", "--targets", f, "--quick"],
    "session": lambda f: ["analyze", f],
    "capture": lambda f: ["natnet", "decode", f],
}


@pytest.mark.skipif(not hasattr(os, "mkfifo") or not Path("/dev/zero").exists(), reason="needs POSIX FIFOs")
@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_file_input_that_is_not_a_file_of_its_size_is_one_line(tmp_path, command, kind):
    path = KINDS[kind](tmp_path)
    t0 = time.monotonic()
    res = CliRunner().invoke(app, COMMANDS[command](str(path)))
    took = time.monotonic() - t0
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise AssertionError(f"traceback instead of one line: {res.exception!r}") from res.exception
    errors = [ln for ln in res.output.splitlines() if ln.startswith("beambench: error:")]
    assert res.exit_code == 2, res.output
    assert len(errors) == 1 and str(path) in errors[0], res.output
    assert took < 5.0, f"{took:.1f} s: was the file read?"


def test_a_2_gb_targets_file_is_refused_before_it_is_read(tmp_path):
    """The issue's case, as a user runs it (a fresh process): seconds and memory of the imports only."""
    big = _big(tmp_path)
    src = str(ROOT / "src")
    env = dict(os.environ, PYTHONPATH=os.environ.get("PYTHONPATH") or src)
    t0 = time.monotonic()
    res = subprocess.run(
        [sys.executable, "-m", "beambench.cli", "calibrate", "sim", "--targets", str(big), "--quick"],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    took = time.monotonic() - t0
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert "2.0 GB" in lines[0] and "targets file" in lines[0], lines
    assert took < 30, took


def test_a_load_cell_calibration_file_is_checked_too(tmp_path):
    from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration
    from beambench.common.yaml_config import ConfigError

    for path in (_big(tmp_path), tmp_path, Path("/dev/zero")):
        with pytest.raises(ConfigError) as err:
            LoadCellCalibration.load(path)
        assert str(path) in str(err.value) and "\n" not in str(err.value)
