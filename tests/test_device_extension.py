"""Adding a device stream is one module (its driver, its emulated peer, its rig-file section and its registration)
and its line in the import list of ``devices/streams``: the toy laser head listed in docs/extending.md ("A real
device", taken from the page itself) is added to a copy of the package exactly as the page shows, and with no other
edit an emulated run (the peer in the peers' process, the driver over UDP loopback) records the stream in the session
file, measuring what the mocap measures; the hardware rig built from a rig file receives it over UDP from a head on
this machine; rig files take its ``laser:`` section, checked field by field; and the doctor gives it a row from
its ping. A copy, because the registries are
process-wide and the package folder is no place for test output."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from beambench.sinks.session_file.reader import read_session
from package_copy import apply_hunk, copy_package, run_copy

ROOT = Path(__file__).resolve().parents[1]


def _the_documented_change() -> tuple[list[tuple[str, str]], str, list[str]]:
    """([(new module's path, its text)], the file the one-line registration edits, its hunk's lines) as
    docs/extending.md's "A real device" section lists them."""
    text = (ROOT / "docs" / "extending.md").read_text()
    section = text.split("\n### A real device", 1)[1].split("\n## ", 1)[0]
    modules = re.findall(r"```python\n# src/beambench/(\S+\.py)\n(.*?)```", section, re.S)
    diffs = re.findall(r"```diff\n--- a/src/beambench/(\S+)\n\+\+\+ b/\S+\n@@[^\n]*\n(.*?)```", section, re.S)
    assert len(diffs) == 1, "docs/extending.md: the device recipe is not one registration"
    return modules, diffs[0][0], diffs[0][1].splitlines()


def test_the_recipe_is_one_module_and_its_line_in_the_import_list():
    modules, registration, hunk = _the_documented_change()
    assert [path for path, _ in modules] == ["devices/streams/laser.py"]  # one new module, nothing else
    assert registration == "devices/streams/__init__.py"
    assert [line for line in hunk if line.startswith(("+", "-"))] == ["+    laser,"]
    ((_, text),) = modules  # the module holds both ends of the wire: the driver and the emulated peer
    assert "class UdpLaser(StreamDriver)" in text and "class LaserPeer" in text and "@device_stream(" in text


@pytest.fixture(scope="module")
def package_with_laser(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the installed package (its data links followed) with the documented change applied: the new
    module and its line in the import list, nothing else."""
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


# on the copy: the hardware rig built from a rig file whose laser: section points at the module's own head (its
# emulated peer, here in this process and measuring a marker held 12.3 mm high); the rig's laser stream receives it
HARDWARE = """
import json, sys, threading, time
import numpy as np
from beambench.backends.hardware import build_device_rig
from beambench.devices.peer import PeerContext
from beambench.devices.streams.laser import LaserPeer

class Held:
    markers = ("stage", "tip", "foot")
    def positions(self, t):
        return np.array([[0.0, 0.0, 0.0], [0.0, 0.1, 0.02], [0.0, 0.2, 0.0123]])
    def positions_at(self, host_s):
        return self.positions(host_s)
    def force(self, t):
        return 0.0, 0.0

peer = LaserPeer(PeerContext(Held()))
(section,) = peer.open().values()
rig_file = sys.argv[1]
with open(rig_file, "w") as f:
    f.write("laser: {address: %s, port: %d}\\n" % (section["address"], section["port"]))
rig = build_device_rig(Held.markers, rig_file)
laser = rig.laser
laser.start()
peer.start()
batches, deadline, poll = [], time.monotonic() + 30, threading.Event()
while sum(len(b) for b in batches) < 200 and time.monotonic() < deadline:
    batches.append(laser.read())
    poll.wait(0.02)  # the poll interval
laser.stop()
peer.stop()
peer.close()
rig.close()
print(json.dumps({
    "streams": list(rig.named),
    "identity": rig.identity()["laser"],
    "height": np.concatenate([b.columns["data"] for b in batches]).tolist(),
    "seq": np.concatenate([b.columns["seq"] for b in batches]).tolist(),
    "health": rig.device_health()["laser"],
}))
"""


def _script_on_copy(script: str, package: Path, tmp_path: Path) -> Any:
    """Run ``script`` with the copy on the path and a rig file path as its argument; its last line's JSON."""
    res = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path / "rig.yaml")],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(package)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_the_hardware_rig_receives_the_new_stream_from_its_rig_files_address(package_with_laser, tmp_path):
    got = _script_on_copy(HARDWARE, package_with_laser, tmp_path)
    assert got["streams"] == ["mocap", "loadcells", "laser"] and got["identity"] == "UdpLaser"
    assert len(got["height"]) >= 200 and set(got["height"]) == {0.0123}  # the held marker's height, over UDP
    assert np.all(np.diff(got["seq"]) >= 1) and got["health"]["garbled"] == 0


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


# on the copy: the doctor's row for the new stream, from its ping: the head answering (its emulated peer on
# loopback, started) and a port nobody listens on
DOCTOR = """
import json, socket, sys
import numpy as np
from beambench.backends.hardware import load_wiring
from beambench.devices.peer import PeerContext
from beambench.devices.streams.laser import LaserPeer
from beambench.session.doctor import Machine, check_machine

class Held:
    markers = ("stage", "tip", "foot")
    def positions_at(self, host_s):
        return np.zeros((3, 3))

peer = LaserPeer(PeerContext(Held()))
(section,) = peer.open().values()
peer.start()
with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
    s.bind(("127.0.0.1", 0))
    closed = s.getsockname()[1]
rows = {}
for name, port in (("answers", section["port"]), ("closed", closed)):
    with open(sys.argv[1], "w") as f:
        f.write("laser: {address: 127.0.0.1, port: %d}\\n" % port)
    rows[name] = [vars(r) for r in check_machine(Machine(load_wiring(sys.argv[1]), sim_only=True))]
peer.stop()
peer.close()
print(json.dumps(rows))
"""


def test_the_doctor_gives_the_new_stream_a_row_from_its_ping(package_with_laser, tmp_path):
    rows = _script_on_copy(DOCTOR, package_with_laser, tmp_path)
    laser = {name: [r for r in got if r["part"] == "laser head (UDP)"] for name, got in rows.items()}
    assert [r["state"] for r in laser["answers"]] == ["ok"], rows["answers"]
    assert [r["state"] for r in laser["closed"]] == ["missing"], rows["closed"]
    assert "no answer" in laser["closed"][0]["found"] and "laser: section" in laser["closed"][0]["todo"]
    parts = [r["part"] for r in rows["answers"]]
    assert parts.index("mocap (NatNet)") < parts.index("load cells (serial)") < parts.index("laser head (UDP)")
