"""No command writes through a symbolic link (docs/safety.md, "Outputs never through a link"): a link planted where a
command's default output goes (its report folder, fit folder, parameter set, calibration, table, recording,
picture) is a taken name, refused in one line (exit 2) before any work, and nothing is written where it points.
``calibrate loadcells --out`` is checked before the first load is asked for; a save that still fails prints the
measured calibration."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml

from beambench.common.resources import USER_DIR_ENV
from conftest import SHORT_RELEASE, cli, one_line_error, record_sim_sessions, unwritable_folder

CONTACT = "name: t\nsweep: {frequencies: [5]}\nsettle_s: 0.2\nrecord_s: 0.3\n"


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> dict[str, Path]:
    return record_sim_sessions(tmp_path_factory.mktemp("real"), {"contact": CONTACT, "release": SHORT_RELEASE})


@pytest.fixture()
def user(tmp_path, monkeypatch) -> Path:
    """A per-user folder of the test's own (where the defaults of calibrate, sweep and bench go)."""
    folder = tmp_path / "user"
    monkeypatch.setenv(USER_DIR_ENV, str(folder))
    return folder


# each case: (where the link goes, given the sessions' copies and the user folder; the command)
Case = tuple[Callable[[dict[str, Path], Path], Path], Callable[[dict[str, Path], Path], list[str]]]
CASES: dict[str, Case] = {
    "analyze report folder": (
        lambda s, u: s["contact"].with_name("contact_report"),
        lambda s, u: ["analyze", str(s["contact"]), "--figures", "none", "--no-write"],
    ),
    "compare report folder": (
        lambda s, u: s["contact"].with_name("contact_vs_other_report"),
        lambda s, u: ["compare", str(s["contact"]), str(s["other"]), "--figures", "none", "--no-write"],
    ),
    "fit folder": (
        lambda s, u: s["release"].with_name("release_fit"),
        lambda s, u: ["fit", str(s["release"]), "--max-iters", "1", "--no-write"],
    ),
    "fit parameter set": (
        lambda s, u: u / "sim_backend" / "prb3_release.yaml",
        lambda s, u: ["fit", str(s["release"]), "--max-iters", "1", "--out", str(s["release"].with_name("f"))],
    ),
    "calibrate loadcells": (
        lambda s, u: u / "calibration" / "loadcells-emulated.yaml",
        lambda s, u: ["calibrate", "loadcells", "--emulate", "--yes", "--duration", "0.05", "--settle", "0"],
    ),
    "calibrate sim evaluation log": (
        lambda s, u: u / "calibration" / "contact_calibrated.evals.jsonl",
        lambda s, u: ["calibrate", "sim", str(s["contact"]), "--quick"],
    ),
    "sweep table": (
        lambda s, u: u / "sweeps" / "ok.parquet",
        lambda s, u: ["sweep", str(s["sweep"])],
    ),
    "bench ladder folder": (
        lambda s, u: u / "bench" / "models",
        lambda s, u: ["bench", "models", "--quick"],
    ),
    "view screenshot": (
        lambda s, u: s["contact"].with_name("shot.png"),
        lambda s, u: ["view", str(s["contact"]), "--screenshot", str(s["contact"].with_name("shot.png"))],
    ),
    "natnet decode table": (
        lambda s, u: s["contact"].with_name("frames.csv"),
        lambda s, u: ["natnet", "decode", str(s["contact"]), "--out", str(s["contact"].with_name("frames.csv"))],
    ),
}


@pytest.mark.parametrize("target_exists", [True, False], ids=["link to a file or folder", "dangling link"])
@pytest.mark.parametrize("case", sorted(CASES))
def test_a_link_planted_at_an_output_is_a_taken_name(case, target_exists, sessions, user, tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    copies = {rig: Path(shutil.copy(path, work / path.name)) for rig, path in sessions.items()}
    copies["other"] = Path(shutil.copy(sessions["contact"], work / "other.h5"))
    copies["sweep"] = work / "ok.yaml"
    copies["sweep"].write_text("name: ok\nfrequencies: [5]\nsettle_s: 0.1\nrecord_s: 0.1\n")
    where, command = CASES[case]
    link = where(copies, user)
    link.parent.mkdir(parents=True, exist_ok=True)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    is_folder = not link.suffix or link.name.endswith(("_report", "_fit", "models"))
    target = elsewhere / ("dir" if is_folder else "file")
    if target_exists:
        target.mkdir() if is_folder else target.write_text("kept\n")
    link.symlink_to(target, target_is_directory=is_folder)
    before = sorted(p.relative_to(elsewhere) for p in elsewhere.rglob("*"))
    line = one_line_error(*cli(*command(copies, user)), "symbolic link")
    assert str(link) in line, line
    assert sorted(p.relative_to(elsewhere) for p in elsewhere.rglob("*")) == before  # nothing written there
    if target_exists and not is_folder:
        assert target.read_text() == "kept\n"


def test_view_never_records_into_a_link_named_like_its_default_recording(sessions, tmp_path):
    """``view --rerun save`` picks a free name: a link (even a dangling one) is taken, as an existing file is."""
    session = Path(shutil.copy(sessions["contact"], tmp_path / "s.h5"))
    link = tmp_path / "s_view.rrd"
    link.symlink_to(tmp_path / "elsewhere.rrd")
    code, out = cli("view", str(session), "--rerun", "save")
    assert code == 0, out
    assert not (tmp_path / "elsewhere.rrd").exists() and (tmp_path / "s_view_1.rrd").is_file()


# --- calibrate loadcells --out: checked first, the matrix printed if saving still fails -------------------------
@pytest.mark.parametrize("place", ["/dev/full", "a folder", "a read-only folder", "a missing folder's file"])
def test_calibrate_loadcells_out_is_checked_before_any_load(place, tmp_path):
    out = {
        "/dev/full": Path("/dev/full"),
        "a folder": tmp_path,
        "a read-only folder": unwritable_folder(tmp_path) / "c.yaml",
        "a missing folder's file": Path("/proc/self/nothing/c.yaml"),
    }[place]
    code, output = cli("calibrate", "loadcells", "--emulate", "--yes", "--out", str(out))
    one_line_error(code, output, "--out", str(out))
    assert "tare" not in output.lower() and "load 1" not in output.lower()  # refused before the walk began


def test_a_calibration_that_cannot_be_saved_at_the_end_is_printed(tmp_path, monkeypatch):
    """The place passed the first check but fails when saving (the disk filled meanwhile): the measured
    calibration is printed as the YAML it would have saved, so the operator's loads are not lost; exit 1."""
    from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration

    out = tmp_path / "c.yaml"

    def full_disk(self: LoadCellCalibration, path: str | Path) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(LoadCellCalibration, "save", full_disk)
    code, output = cli(
        "calibrate", "loadcells", "--emulate", "--yes", "--duration", "0.05", "--settle", "0", "--out", str(out)
    )
    errors = [ln for ln in output.splitlines() if ln.startswith("beambench: error:")]
    assert code == 1 and len(errors) == 1 and "No space left" in errors[0], output
    printed = output[output.index("# not saved") : output.index("beambench: error:")]
    cal = yaml.safe_load(printed)
    assert len(cal["matrix_n_per_count"]) == 2 and len(cal["matrix_n_per_count"][0]) == 4
    assert all(isinstance(v, float) for row in cal["matrix_n_per_count"] for v in row)
    assert not out.exists()
