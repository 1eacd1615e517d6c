"""Adding a device stream is a driver module, its emulated peer's module and one registration: the toy laser head
listed in docs/extending.md ("A real device", taken from the page itself) is added to a copy of the package
exactly as the page shows, and with no other edit an emulated run (the peer in the peers' process, the driver over
UDP loopback) records the stream in the session file, measuring what the mocap measures, and rig files take its
``laser:`` section, checked field by field. A copy, because the registries are process-wide and the package folder
is no place for test output."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from beambench.sinks.session_file.reader import read_session
from package_copy import apply_hunk, copy_package, run_copy

ROOT = Path(__file__).resolve().parents[1]


def _the_documented_change() -> tuple[list[tuple[str, str]], str, list[str]]:
    """([(new module's path, its text)], the file the registration edits, its hunk's lines) as
    docs/extending.md's "A real device" section lists them."""
    text = (ROOT / "docs" / "extending.md").read_text()
    section = text.split("\n### A real device", 1)[1].split("\n## ", 1)[0]
    modules = re.findall(r"```python\n# src/beambench/(\S+\.py)\n(.*?)```", section, re.S)
    diffs = re.findall(r"```diff\n--- a/src/beambench/(\S+)\n\+\+\+ b/\S+\n@@[^\n]*\n(.*?)```", section, re.S)
    assert len(diffs) == 1, "docs/extending.md: the device recipe is not one registration"
    return modules, diffs[0][0], diffs[0][1].splitlines()


def test_the_recipe_is_a_driver_an_emulated_peer_and_one_registration():
    modules, registration, _ = _the_documented_change()
    assert sorted(path.split("/")[0] for path, _ in modules) == ["devices", "emulators"]
    assert registration == "backends/hardware.py"


@pytest.fixture(scope="module")
def package_with_laser(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the installed package (its data links followed) with the documented change applied: the two new
    modules and the one registration, nothing else."""
    modules, registration, hunk = _the_documented_change()
    src = tmp_path_factory.mktemp("src")
    pkg = copy_package(src)
    for path, text in modules:
        assert not (pkg / path).exists()
        (pkg / path).write_text(text)
    target = pkg / registration
    target.write_text(apply_hunk(target.read_text(), hunk))
    return src


PROTOCOL = """name: laser
rig: contact
backend: emulated
sweep: {frequencies: [12]}
settle_s: 0.5
record_s: 1.0
sim: {model: prb3, noise: false}
"""


def test_an_emulated_run_records_the_new_stream_measuring_the_marker(package_with_laser, tmp_path):
    protocol = tmp_path / "laser.yaml"
    protocol.write_text(PROTOCOL)
    res = run_copy(
        package_with_laser, "run", str(protocol), "--rerun", "off", "--name", "s", "--out", str(tmp_path), cwd=tmp_path
    )
    assert res.returncode == 0, res.stderr
    s = read_session(tmp_path / "s.h5")
    laser, mocap = s.streams["laser"], s.streams["mocap"]
    assert laser.spec.columns["data"].unit == "m" and laser.spec.rate_hz == 500.0
    seq = laser.columns["seq"]
    assert len(laser) > 0.8 * 500.0 * 1.5 and (np.diff(seq) >= 1).all()  # received over the whole run, in order
    assert s.general["devices"]["laser"]["received"] >= len(laser)  # the driver's counters, in /general
    assert s.general["identity"]["laser"] == "UdpLaser"  # a stream of the rig, beside mocap and load cells
    # what it measures: the last marker's height, as the mocap (Motive's y-up frame) saw it at the same device
    # times (both peers stamp their samples on the host's clock: no offset, no drift)
    inside = (laser.device_time >= mocap.device_time[0]) & (laser.device_time <= mocap.device_time[-1])
    assert inside.mean() > 0.9
    seen = np.interp(laser.device_time[inside], mocap.device_time, mocap.columns["data"][:, -1, 1])
    height = laser.columns["data"][inside]
    assert np.ptp(height) > 1e-4  # the marker moves: a constant would not tell
    # most samples agree to a fraction of a percent of the motion (a sample taken while the peers' physics thread
    # lagged behind, on a loaded host, reads an older row: a few percent off), over the same range
    off = np.abs(height - seen) / np.ptp(height)
    assert np.median(off) < 0.005, np.quantile(off, [0.5, 0.95, 1.0])
    assert np.ptp(height) == pytest.approx(np.ptp(seen), rel=0.1)


def test_a_rig_file_takes_the_new_section_checked_field_by_field(package_with_laser, tmp_path):
    protocol = tmp_path / "laser.yaml"
    protocol.write_text(PROTOCOL.replace("backend: emulated", "backend: hardware"))
    rig = tmp_path / "rig.yaml"
    rig.write_text("laser: {address: 10.0.0.7, port: 5006}\n")
    res = run_copy(package_with_laser, "run", str(protocol), "--rig", str(rig), "--dry-run", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    rig.write_text("laser: {address: 10.0.0.7, port: 70000}\n")
    res = run_copy(package_with_laser, "run", str(protocol), "--rig", str(rig), "--dry-run", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert "laser.port" in res.stderr and "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
