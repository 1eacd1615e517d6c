"""A new user's first hour: shipped data found from any folder, user files out of the package, clean help and
output, a dry run that says how long the run takes, calibration with no stdin, the quick-start commands."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

import beambench
from beambench.cli import app
from beambench.common import resources
from beambench.sim.models.params import available, load_params
from beambench.sinks.hdf5 import read_session
from conftest import REPO, SHARED_ENV, require_shared, shared_path

TINY = """
name: tiny
rig: contact
sweep: {frequencies: [5, 30]}
settle_s: 0.2
record_s: 0.3
limits: {max_frequency_hz: 40}
sim: {seed: 1, params: PARAMS}
"""


def _beambench(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "COLUMNS": "80"}
    return subprocess.run(
        [sys.executable, "-m", "beambench", *args],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=cwd,
        stdin=subprocess.DEVNULL,
        env=env,
    )


# --------------------------------------------------------------------------- shipped data and the user folder


def test_shipped_data_is_found_inside_the_package_not_beside_the_source():
    pkg = Path(beambench.__file__).parent
    for name, files in {
        "sim_backend": ("prb3_paper.yaml", "contact_table.csv", "ladder_table.csv"),
        "calibration": ("rig.yaml", "loadcells.yaml"),
        "protocols": ("contact_sweep.yaml", "twist_sweep.yaml"),
    }.items():
        folder = resources.shipped_dir(name)
        assert folder == pkg / "data" / name
        assert all((folder / f).is_file() for f in files)
    assert set(resources.shipped_protocols()) >= {"contact_sweep", "release_test", "walker_sweep"}


def test_named_parameter_sets_are_found_in_the_user_folder_too(tmp_path, monkeypatch):
    monkeypatch.setenv(resources.USER_DIR_ENV, str(tmp_path))
    assert resources.user_dir("sim_backend") == tmp_path / "sim_backend"
    assert "mine" not in available()
    text = resources.shipped_dir("sim_backend").joinpath("prb3_paper.yaml").read_text().replace("0.340", "0.5", 1)
    (tmp_path / "sim_backend").mkdir()
    (tmp_path / "sim_backend" / "prb3_mine.yaml").write_text(text)
    assert {"mine", "paper"} <= set(available())
    assert load_params("mine").k == 0.5 and load_params("paper").k == 0.34


def test_an_absolute_params_path_from_another_folder_still_uses_the_measured_timestep_table(tmp_path, monkeypatch):
    params = tmp_path / "my_beam.yaml"
    shutil.copy(resources.shipped_dir("sim_backend") / "prb3_paper.yaml", params)
    proto = tmp_path / "tiny.yaml"
    proto.write_text(TINY.replace("PARAMS", str(params)))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    res = CliRunner().invoke(app, ["run", str(proto), "--rerun", "off", "--out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    session = read_session(res.stdout.strip().splitlines()[-1])
    selection = session.general["identity"]["model"]["selection"]
    assert selection["table"] == "contact_table.csv" and set(selection["timesteps"]) == {"5", "30"}
    assert not any(elsewhere.iterdir())  # nothing written into the current folder


def test_a_shipped_protocol_runs_by_name_from_any_folder(tmp_path):
    res = _beambench("run", "contact_sweep", "--dry-run", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "contact_sweep on the contact rig" in res.stdout


# --------------------------------------------------------------------------- dry run: how long it takes here


def test_dry_run_says_how_long_the_run_takes_on_this_backend(tmp_path):
    sim = _beambench("run", "contact_sweep", "--dry-run", cwd=tmp_path)
    emulated = _beambench("run", "contact_sweep", "--dry-run", "--backend", "emulated", cwd=tmp_path)
    assert sim.returncode == 0 and emulated.returncode == 0, sim.stderr + emulated.stderr
    assert "total duration: 280 s of rig time" in sim.stdout
    sim_line = next(ln for ln in sim.stdout.splitlines() if ln.startswith("expected run time here:"))
    # from the measured timing table where the protocol's model has one, else from the measured stepping costs
    assert "of stepping" in sim_line and ("contact_table.csv" in sim_line or "step_costs.csv" in sim_line)
    # "about 67 s", or in minutes from 90 s on ("about 1.8 min": this machine timed under load by other work)
    number, unit = sim_line.split("about ")[1].split()[:2]
    assert unit in ("s", "min"), sim_line
    seconds = float(number) * (60 if unit == "min" else 1)
    assert 1 < seconds < 280  # the sim's estimate from its table, not the rig time
    assert "expected run time here: 4.7 min (real time on the emulated backend)" in emulated.stdout


# --------------------------------------------------------------------------- calibration: no stdin, user folder


def test_calibrate_with_loads_and_yes_reads_no_stdin_and_writes_to_the_user_folder(tmp_path):
    user = Path(os.environ[resources.USER_DIR_ENV])
    shipped = sorted(p.name for p in resources.shipped_dir("calibration").iterdir())
    args = ["calibrate", "loadcells", "--emulate", "--yes", "--loads", "0,0 5,0 0,5 5,5"]
    res = _beambench(*args, "--duration", "0.1", "--settle", "0", cwd=tmp_path)  # stdin is /dev/null
    assert res.returncode == 0, res.stderr
    out = user / "calibration" / "loadcells-emulated.yaml"
    assert res.stdout.strip() == str(out) and out.is_file()
    assert "RMS residual" in res.stderr and "press Enter" not in res.stderr
    assert sorted(p.name for p in resources.shipped_dir("calibration").iterdir()) == shipped
    assert not any(tmp_path.iterdir())


# --------------------------------------------------------------------------- help and output


def _commands(group, path: tuple[str, ...] = ()):
    """Every leaf command under ``group`` (typer vendors its own click, so by shape, not by class)."""
    for name, cmd in group.commands.items():
        if hasattr(cmd, "commands"):
            yield from _commands(cmd, (*path, name))
        else:
            yield (*path, name), cmd


def test_every_help_shows_types_only_for_values_and_never_breaks_a_paragraph():
    root = typer.main.get_command(app)
    commands = list(_commands(root))
    assert len(commands) >= 10
    for path, cmd in commands:
        res = CliRunner().invoke(app, [*path, "--help"], terminal_width=80)
        assert res.exit_code == 0, (path, res.output)
        assert "<bool>" not in res.stdout and "╭" not in res.stdout, path
        for param in cmd.params:
            if param.param_type_name != "option" or param.hidden:
                continue
            long = max(param.opts, key=len)
            options = res.stdout.split("\nOptions:\n", 1)[1].splitlines()
            line = next(ln for ln in options if f"{long} " in ln or ln.endswith(long))
            shown = line.split(long, 1)[1].split("  ")[0].strip()
            if param.is_flag:
                assert shown in ("",) or shown.startswith("/"), (path, line)  # a flag shows no type
            else:
                assert shown, (path, line)  # a value shows its type or metavar
        # The description's paragraphs are rewrapped: no short line inside a paragraph (a source line break)
        description = res.stdout.split("\n\n", 1)[1].split("\nArguments:")[0].split("\nOptions:")[0]
        for para in description.split("\n\n"):
            lines = para.rstrip().splitlines()
            assert all(len(ln) >= 55 for ln in lines[:-1]), (path, para)


def test_version():
    res = _beambench("--version")
    assert res.returncode == 0 and res.stdout.strip() == f"beambench {beambench.__version__}"


# --------------------------------------------------------------------------- shared fixtures, quick start


def test_shared_fixtures_are_found_through_the_environment_variable(tmp_path, monkeypatch):
    (tmp_path / "fixtures" / "natnet").mkdir(parents=True)
    (tmp_path / "fixtures" / "natnet" / "x.bin").write_bytes(b"1")
    monkeypatch.setenv(SHARED_ENV, str(tmp_path))
    assert shared_path("fixtures", "natnet", "x.bin") == tmp_path / "fixtures" / "natnet" / "x.bin"
    assert require_shared("fixtures", "natnet", "x.bin").read_bytes() == b"1"
    monkeypatch.delenv(SHARED_ENV)
    assert shared_path("fixtures") == REPO.parent / "shared" / "fixtures"


def test_a_missing_shared_fixture_skips_here_and_fails_in_ci(tmp_path, monkeypatch):
    monkeypatch.setenv(SHARED_ENV, str(tmp_path))  # an empty shared folder
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match="not found"):
        require_shared("fixtures", "natnet", "x.bin")
    monkeypatch.setenv("CI", "1")
    with pytest.raises(pytest.fail.Exception, match="CI must run this test"):
        require_shared("fixtures", "natnet", "x.bin")


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
def test_quick_start_make_targets_build_a_venv_from_the_project_and_run_the_sweep():
    res = subprocess.run(
        ["make", "-n", "run", "test", "VENV=/nonexistent-venv"], cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0, res.stderr
    assert "-m venv /nonexistent-venv" in res.stdout
    assert 'pip install --quiet -e ".[dev]"' in res.stdout
    assert "/nonexistent-venv/bin/beambench run protocols/contact_sweep.yaml" in res.stdout
    assert "pytest" in res.stdout and "lint-imports" in res.stdout
