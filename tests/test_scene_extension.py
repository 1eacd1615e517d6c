"""Adding a scene is one new module plus one declaration line: the toy scene listed in docs/extending.md (taken
from the page itself) is added to a copy of the package exactly as the page shows, and with no other edit
``beambench run`` runs a protocol on it, ``beambench analyze`` reads the session and ``beambench sweep`` batches it
(a worker process included). A copy, because the scene catalogue and the registries are process-wide and the
package folder is no place for test output."""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd
import pytest

from package_copy import copy_package, run_copy

ROOT = Path(__file__).resolve().parents[1]
CATALOGUE = Path("acquisition/protocol/scenes.py")
IMPORT_LIST = Path("sim/scenes/__init__.py")


def _the_documented_change() -> tuple[str, tuple[str, str], str, str]:
    """(declaration line, (import list's context line, the line added after it), module path, module text) as
    docs/extending.md's "A scene" section lists them."""
    text = (ROOT / "docs" / "extending.md").read_text()
    section = text.split("\n## A scene\n", 1)[1].split("\n## ", 1)[0]
    declaration = re.search(r"^\+(\w+ = declare\(SceneInfo\(.*\)\))$", section, re.M)
    listed = re.search(r"^--- a/src/beambench/sim/scenes/__init__.py\n.*?^ ([^\n]+)\n\+([^\n]+)$", section, re.M | re.S)
    module = re.search(r"```python\n# src/beambench/(sim/scenes/\w+\.py)\n(.*?)```", section, re.S)
    assert declaration and listed and module, "docs/extending.md lists no declaration, import line or scene module"
    return declaration.group(1), (listed.group(1), listed.group(2)), module.group(1), module.group(2)


@pytest.fixture(scope="module")
def package_with_toy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the installed package (its data links followed) with the documented change applied."""
    declaration, (after, line), module_path, module_text = _the_documented_change()
    src = tmp_path_factory.mktemp("src")
    pkg = copy_package(src)
    assert not (pkg / module_path).exists()
    (pkg / module_path).write_text(module_text)
    with (pkg / CATALOGUE).open("a") as f:
        f.write(declaration + "\n")
    listing = pkg / IMPORT_LIST
    text = listing.read_text()
    assert text.count(after + "\n") == 1, f"{IMPORT_LIST}: the page's context line {after!r} is not there once"
    listing.write_text(text.replace(after + "\n", f"{after}\n{line}\n"))
    return src


PROTOCOL = """name: toy
rig: weightless
backend: sim
sweep: {frequencies: [15]}
settle_s: 0.5
record_s: 0.5
sim: {model: prb3, twist_deg: 90, noise: false}
"""


def test_a_new_scene_module_and_its_declaration_line_make_a_runnable_and_sweepable_scene(package_with_toy, tmp_path):
    protocol = tmp_path / "toy_protocol.yaml"
    protocol.write_text(PROTOCOL)
    res = run_copy(package_with_toy, "run", str(protocol), "--rerun", "off", "--out", str(tmp_path), cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    (session,) = tmp_path.glob("toy_*.h5")
    res = run_copy(package_with_toy, "analyze", str(session), "--out", str(tmp_path / "report"), cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    # its flags (driven, a stage, no plate, no body) pick its figures: the driven rig's, none of the plate's
    assert {p.stem for p in (tmp_path / "report").glob("*.png")} >= {"trajectories", "ellipse", "frequency"}
    assert not {p.stem for p in (tmp_path / "report").glob("*.png")} & {"forces", "contact_frequency", "gait"}
    step = pd.read_csv(tmp_path / "report" / "steps.csv").iloc[0]
    assert step["status"] == "done" and step["stage_amplitude_mm"] == pytest.approx(2.0, rel=1e-3)

    sweep = tmp_path / "toy.yaml"
    sweep.write_text(
        "scene: weightless\ngrid: {twist_deg: [0, 90], chirality: [1, -1]}\n"
        "frequencies: [15]\nsettle_s: 0.3\nrecord_s: 0.4\n"
    )
    out = tmp_path / "toy.parquet"
    res = run_copy(
        package_with_toy, "sweep", str(sweep), "--out", str(out), "--workers", "1", "--no-figure", cwd=tmp_path
    )
    assert res.returncode == 0, res.stderr
    table = pd.read_parquet(out).set_index(["twist_deg", "chirality"])
    assert set(table["scene"]) == {"weightless"} and table["ok"].all()
    # physics of the weightless beam: untwisted, the straight beam is symmetric about the drive's plane, so the
    # tip stays in it (no vertical motion at all); twisted, bending couples into z and the tip orbits an ellipse
    flat, twisted = table.loc[(0.0, 1)], table.loc[(90.0, 1)]
    assert flat["tip_major_mm"] > 1.0 and flat["tip_minor_mm"] < 1e-6 * flat["tip_major_mm"]
    assert twisted["tip_minor_mm"] > 0.01 * twisted["tip_major_mm"]
    # and the mirror image (chirality −1) orbits the mirrored ellipse: same axes, opposite sense and tilt
    mirror = table.loc[(90.0, -1)]
    assert mirror["tip_major_mm"] == pytest.approx(twisted["tip_major_mm"], rel=1e-6)
    assert mirror["tip_minor_mm"] == pytest.approx(twisted["tip_minor_mm"], rel=1e-6)
    assert mirror["tip_tilt_deg"] == pytest.approx(-twisted["tip_tilt_deg"], abs=1e-6)
    assert {twisted["tip_sense"], mirror["tip_sense"]} == {"cw", "ccw"}
    # the run (servo-driven stage, ramped crank) and the batched sweep (feed-forward stage) simulate one beam: at
    # 15 Hz the session's tip ellipse relative to the stage is the sweep's
    assert step["tip_major_mm"] == pytest.approx(twisted["tip_rel_major_mm"], rel=0.02)
    assert step["tip_minor_mm"] == pytest.approx(twisted["tip_rel_minor_mm"], rel=0.05)


def test_the_new_scene_refuses_another_scenes_option_in_one_line(package_with_toy, tmp_path):
    sweep = tmp_path / "bad.yaml"
    sweep.write_text("scene: weightless\nbase: {gap_mm: 2.0}\nfrequencies: [15]\n")
    res = run_copy(package_with_toy, "sweep", str(sweep), "--dry-run", cwd=tmp_path)
    assert res.returncode == 2
    assert "gap_mm applies to scene: contact only (the weightless scene has no plate)" in res.stderr
    assert "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
