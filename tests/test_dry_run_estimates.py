"""Every shipped protocol's dry run estimates its run time here, and the release test's says
that it drives nothing."""

from __future__ import annotations

import re

from typer.testing import CliRunner

from beambench.cli import app


def _dry_run(name: str) -> str:
    res = CliRunner().invoke(app, ["run", name, "--dry-run"])
    assert res.exit_code == 0, res.output
    return res.stdout


def test_the_walker_dry_run_estimates_from_the_measured_stepping_costs():
    out = _dry_run("walker_sweep")
    line = next(ln for ln in out.splitlines() if ln.startswith("expected run time here:"))
    assert "not estimated" not in line and "from the measured cost table step_costs.csv" in line, line
    assert "2 segments in parallel" in line
    found = re.search(r"about ([\d.]+) (s|min) of stepping", line)
    assert found, line
    seconds = float(found.group(1)) * (60 if found.group(2) == "min" else 1)
    assert 1 < seconds < 1800  # something, not nothing (the machine may be loaded: no tight upper bound)
    assert "max frequency: 80 Hz   amplitude: 2 mm" in out
    # the shipped walker stands on its legs (docs/walker-twin.md): no fold warning (tests/test_walker_leg_statics.py
    # has a walker whose run gives one)
    assert not [ln for ln in out.splitlines() if ln.startswith("warning: ")], out


def test_the_release_dry_run_says_it_drives_nothing():
    out = _dry_run("release_test")
    assert "amplitude:" not in out and "no drive: a 200 g tip load released" in out
    assert "expected run time here: " in out and "not estimated" not in out


def test_the_release_dry_run_says_under_1_s_without_about():
    line = next(ln for ln in _dry_run("release_test").splitlines() if ln.startswith("expected run time here:"))
    assert "about under" not in line, line


def test_a_track_dry_run_counts_its_map_sweep_and_says_where_the_map_goes():
    """``walker_track`` (``map: twin``) runs the protocol's sweep on the sim before the profile: the dry run's
    estimate covers both phases, names them, and says where the map's session goes, its size and that it is kept."""
    out = _dry_run("walker_track")
    text = out[out.index("expected run time here:") :]
    assert "in two phases" in text and "1. the speed map" in text and "2. the profile" in text, text
    assert "53 steps, 132.5 s of rig time" in text and "<session>_map.h5" in text and "MB" in text, text
    assert "kept" in text and "track.map: <that file>" in text
    found = re.search(r"expected run time here: about ([\d.]+) (s|min) in two phases", text)
    assert found, text
    total = float(found.group(1)) * (60 if found.group(2) == "min" else 1)
    phase = re.search(r"1\. the speed map.*?: about ([\d.]+) (s|min) of stepping.*?2 segments in parallel", text, re.S)
    assert phase, text
    map_s = float(phase.group(1)) * (60 if phase.group(2) == "min" else 1)
    assert total >= map_s > 0  # the map is part of the estimate, not left out
    profile = re.search(
        r"2\. the profile: 6 segments, 27 s of rig time on the sim backend: about ([\d.]+) (s|min)", text
    )
    assert profile, text
