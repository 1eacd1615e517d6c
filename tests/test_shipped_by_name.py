"""Shipped files by name from any folder, default outputs in the per-user folder
(shown in --help), nothing written outside --out and that folder, whole lines on a non-terminal stderr."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from beambench.cli import app
from beambench.common import resources
from beambench.common.resources import ShippedFileError, resolve_file, shipped_files

TINY_SWEEP = """
name: tiny_twist
scene: free_beam
base: {model: prb3, params: paper, amplitude_mm: 2.0, integrator: implicitfast, timestep: 2.0e-4}
grid: {twist_deg: [0, 90]}
frequencies: [15]
settle_s: 0.05
record_s: 0.1
"""


def _beambench(*args: str, cwd: Path, user: Path, columns: str | None = None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "COLUMNS"}
    env[resources.USER_DIR_ENV] = str(user)
    if columns:
        env["COLUMNS"] = columns
    return subprocess.run(
        [sys.executable, "-m", "beambench", *args],
        capture_output=True,
        text=True,
        timeout=180,
        cwd=cwd,
        stdin=subprocess.DEVNULL,
        env=env,
    )


def _cli(*args: str) -> tuple[int, str, str]:
    res = CliRunner().invoke(app, list(args))
    return res.exit_code, res.stdout, res.stderr


def _files(folder: Path) -> set[Path]:
    return {p.relative_to(folder) for p in folder.rglob("*") if p.is_file()}


def test_every_kind_is_found_by_name_file_name_and_shipped_path_from_any_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for kind, name, folder in [
        ("protocol", "contact_sweep", "protocols"),
        ("sweep", "twist_sweep", "protocols"),
        ("targets", "paper_contact_targets", "calibration"),
        ("params", "prb3_paper", "sim_backend"),
    ]:
        expected = resources.shipped_dir(folder) / f"{name}.yaml"  # type: ignore[arg-type]
        for given in (name, f"{name}.yaml", f"{folder}/{name}.yaml"):
            assert resolve_file(kind, given) == expected, (kind, given)  # type: ignore[arg-type]
    mine = tmp_path / "mine.yaml"
    mine.write_text("x: 1\n")
    assert resolve_file("sweep", mine) == mine  # a file given by path is taken as it is


def test_the_kinds_do_not_mix_and_an_unknown_name_lists_the_shipped_ones():
    assert set(shipped_files("protocol")) == {"contact_sweep", "release_test", "walker_sweep", "walker_track"}
    assert set(shipped_files("sweep")) == {"chirality_sweep", "twist_sweep"}
    assert set(shipped_files("targets")) == {"paper_contact_targets", "paper_walker_targets"}
    with pytest.raises(ShippedFileError, match=r"a shipped sweep file, not a protocol.*beambench sweep twist_sweep"):
        resolve_file("protocol", "twist_sweep")
    with pytest.raises(ShippedFileError, match=r"no such targets file.*paper_contact_targets, paper_walker_targets"):
        resolve_file("targets", "paper_targets")
    with pytest.raises(ShippedFileError, match="no such sweep file"):
        resolve_file("sweep", "elsewhere/twist_sweep.yaml")  # a path in another folder is not a shipped name


HELPS = """
from typer.testing import CliRunner
from beambench.cli import app
for args in (["run"], ["sweep"], ["bench", "models"], ["calibrate", "sim"]):
    print("".join(CliRunner().invoke(app, [*args, "--help"]).stdout.split()))
"""


def test_help_lists_only_what_each_command_takes_and_the_folder_it_writes_to(tmp_path):
    """In a fresh process (help texts are made when the CLI is built), one interpreter for all four."""
    user = tmp_path / "user"
    env = {**os.environ, resources.USER_DIR_ENV: str(user)}
    res = subprocess.run([sys.executable, "-c", HELPS], capture_output=True, text=True, env=env, cwd=tmp_path)
    run, sweep, bench, calib = res.stdout.splitlines()  # whitespace removed: click breaks long paths
    assert "contact_sweep" in run and "twist_sweep" not in run
    assert "twist_sweep" in sweep and "contact_sweep" not in sweep and str(user / "sweeps") in sweep
    assert str(user / "bench" / "models") in bench
    assert "paper_contact_targets" in calib and str(user / "calibration") in calib and ".local/share" not in calib
    assert not any(tmp_path.iterdir())


def test_a_sweep_writes_nothing_outside_the_user_folder_and_keeps_whole_lines_on_stderr(tmp_path):
    """Run from an empty folder with stderr a pipe (not a terminal): the table lands in the per-user folder,
    the current folder stays empty, and the progress line is not cut at 80 columns."""
    work, user, spec = tmp_path / "work", tmp_path / "user", tmp_path / "spec" / "tiny_twist.yaml"
    work.mkdir()
    spec.parent.mkdir()
    spec.write_text(TINY_SWEEP)
    res = _beambench("sweep", str(spec), "--workers", "1", "--no-figure", cwd=work, user=user)
    assert res.returncode == 0, res.stderr
    assert not any(work.iterdir())
    assert _files(user) == {Path("sweeps/tiny_twist.parquet")}
    assert _files(spec.parent) == {Path("tiny_twist.yaml")}
    assert "…" not in res.stderr and "(0 done before) on " in res.stderr


def test_a_shipped_sweep_resolves_by_name_from_an_empty_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = _cli("sweep", "twist_sweep", "--dry-run")
    assert code == 0, err
    assert f"table: {resources.user_dir('sweeps') / 'twist_sweep.parquet'}" in out and "37 points" in out
    assert not any(tmp_path.iterdir())


def test_calibrate_sim_resolves_shipped_targets_by_name_and_path(tmp_path, monkeypatch):
    """A bad --free after the targets are read: the targets resolve (no "no such targets file"), nothing runs."""
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    for given in ("paper_contact_targets", "calibration/paper_contact_targets.yaml"):
        code, _, err = _cli("calibrate", "sim", "--targets", given, "--free", "nope", "--out", str(out))
        assert code == 2 and "contact rig unknowns are" in err, err
    code, _, err = _cli("calibrate", "sim", "--targets", "paper_targets", "--out", str(out))
    assert code == 2 and "shipped: paper_contact_targets, paper_walker_targets" in err
    assert {p.name for p in tmp_path.iterdir()} <= {"out"}
