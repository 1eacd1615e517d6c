"""Issue 23 point 6: every shipped protocol's dry run estimates its run time here, and the release test's says
that it drives nothing."""

from __future__ import annotations

import re

from typer.testing import CliRunner

from beambench.cli import app


def _dry_run(name: str) -> str:
    res = CliRunner().invoke(app, ["run", name, "--dry-run"])
    assert res.exit_code == 0, res.output
    return res.stdout


def test_the_walker_dry_run_estimates_from_a_timed_stretch_of_its_physics():
    out = _dry_run("walker_sweep")
    line = next(ln for ln in out.splitlines() if ln.startswith("expected run time here:"))
    assert "not estimated" not in line and "measured here" in line and "2 segments in parallel" in line
    found = re.search(r"about ([\d.]+) (s|min) of stepping", line)
    assert found, line
    seconds = float(found.group(1)) * (60 if found.group(2) == "min" else 1)
    assert 1 < seconds < 1800  # something, not nothing (the machine may be loaded: no tight upper bound)
    assert "max frequency: 80 Hz   amplitude: 2 mm" in out
    # the shipped walker stands on its legs (docs/walker-twin.md): no fold warning (tests/test_walker_leg_statics.py
    # has a walker whose dry run and run give one)
    assert not [ln for ln in out.splitlines() if ln.startswith("warning: ")], out


def test_the_release_dry_run_says_it_drives_nothing():
    out = _dry_run("release_test")
    assert "amplitude:" not in out and "no drive: a 200 g tip load released" in out
    assert "expected run time here: " in out and "not estimated" not in out
