"""Adding a simulated stream is one new module plus one registration line: the toy laser sensor listed in
docs/extending.md (taken from the page itself) is added to a copy of the package exactly as the page shows, and with
no other edit a sim run records it in the session file, on the clock the protocol gives it in ``sim.clocks``, and
sends it to the Rerun recording. A copy, because the registries are process-wide and the package folder is no place
for test output."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import rerun.chunk as rc

from beambench.sinks.session_file.reader import read_session
from package_copy import apply_hunk, copy_package, run_copy

ROOT = Path(__file__).resolve().parents[1]


def _the_documented_change() -> tuple[str, list[str], str, str]:
    """(file the registration edits, its hunk's lines, module path, module text) as docs/extending.md's
    "A simulated stream" section lists them."""
    text = (ROOT / "docs" / "extending.md").read_text()
    section = text.split("\n### A simulated stream", 1)[1].split("\n### ", 1)[0]
    diff = re.search(r"```diff\n--- a/src/beambench/(\S+)\n\+\+\+ b/\S+\n@@[^\n]*\n(.*?)```", section, re.S)
    module = re.search(r"```python\n# src/beambench/(backends/sim_streams/\w+\.py)\n(.*?)```", section, re.S)
    assert diff and module, "docs/extending.md lists no registration or no stream module"
    return diff.group(1), diff.group(2).splitlines(), module.group(1), module.group(2)


@pytest.fixture(scope="module")
def package_with_laser(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the installed package (its data links followed) with the documented change applied: the new
    module and the one registration edit, nothing else."""
    registration, hunk, module_path, module_text = _the_documented_change()
    src = tmp_path_factory.mktemp("src")
    pkg = copy_package(src)
    assert not (pkg / module_path).exists()
    (pkg / module_path).write_text(module_text)
    target = pkg / registration
    target.write_text(apply_hunk(target.read_text(), hunk))
    return src


OFFSET_S = 0.25  # the laser's clock runs this far ahead of the sim's: its device times show it
PROTOCOL = f"""name: laser
rig: contact
backend: sim
sweep: {{frequencies: [12]}}
settle_s: 0.3
record_s: 0.5
sim: {{model: prb3, noise: false, clocks: {{laser: {{offset_s: {OFFSET_S}}}}}}}
"""


@pytest.fixture(scope="module")
def laser_run(package_with_laser, tmp_path_factory) -> tuple[Path, Path]:
    out = tmp_path_factory.mktemp("run")
    protocol = out / "laser.yaml"
    protocol.write_text(PROTOCOL)
    res = run_copy(
        package_with_laser, "run", str(protocol), "--rerun", "save", "--name", "s", "--out", str(out), cwd=out
    )
    assert res.returncode == 0, res.stderr
    return out / "s.h5", out / "s.rrd"


def test_the_new_stream_is_in_the_session_on_its_own_clock_and_measures_the_marker(laser_run):
    s = read_session(laser_run[0])
    laser, mocap = s.streams["laser"], s.streams["mocap"]
    assert laser.spec.columns["data"].unit == "m" and laser.spec.rate_hz == 2000.0
    # sampled at its rate for the whole run, as the mocap at its own
    assert len(laser) / len(mocap) == pytest.approx(2000.0 / 360.0, rel=0.01)
    # on its own clock: device time = true time + the protocol's offset; host time = true time + 0.5 ms latency
    lag = laser.device_time - laser.host_time_ns * 1e-9
    np.testing.assert_allclose(lag, OFFSET_S - 0.0005, atol=1e-6)
    # what it measures: the last marker's height, as the mocap (ideal clock) saw it at the same true times
    true_s = laser.device_time - OFFSET_S
    seen = np.interp(true_s, mocap.device_time, mocap.columns["data"][:, -1, 2])
    inside = (true_s >= mocap.device_time[0]) & (true_s <= mocap.device_time[-1])
    assert inside.mean() > 0.95
    np.testing.assert_allclose(laser.columns["data"][inside], seen[inside], atol=2e-5)
    assert np.ptp(laser.columns["data"]) > 1e-4  # the foot moves: a constant would not tell
    devices = s.general["identity"]["devices"]
    assert devices["laser"]["rate_hz"] == 2000.0 and devices["laser"]["clock"]["offset_s"] == OFFSET_S


def _rows(rrd: Path) -> dict[str, int]:
    rows: dict[str, int] = {}
    for chunk in rc.RrdReader(rrd).stream():
        if not chunk.is_static:
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    return rows


def test_the_new_stream_is_in_the_rerun_recording_and_its_replay(package_with_laser, laser_run):
    session, rrd = laser_run
    s = read_session(session)
    rows = _rows(rrd)
    assert rows["/laser/data"] == len(s.streams["laser"])
    assert rows["/motor/velocity"] == len(s.streams["motor"])  # the rig's own panels are still fed
    # the session file keeps what the view plots: a replay shows the stream too
    replay = rrd.with_name("replay.rrd")
    res = run_copy(package_with_laser, "view", str(session), "--rerun", "save", "--out", str(replay), cwd=rrd.parent)
    assert res.returncode == 0, res.stderr
    assert _rows(replay)["/laser/data"] == len(s.streams["laser"])


def test_a_clock_for_a_stream_nobody_registered_is_one_line(package_with_laser, tmp_path):
    protocol = tmp_path / "typo.yaml"
    protocol.write_text(PROTOCOL.replace("laser: {", "lazer: {"))
    res = run_copy(package_with_laser, "run", str(protocol), "--dry-run", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert "sim.clocks.lazer" in res.stderr and "'lazer'" in res.stderr and "laser" in res.stderr
    assert "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
