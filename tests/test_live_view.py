"""The live view in the real Rerun viewer (headless, Mesa's software Vulkan where there is no GPU): short contact
and walker runs saved to ``.rrd``, opened in the viewer, read back through Rerun's ``ViewerClient`` (views,
their reports, the blueprint) and looked at in screenshots: what a lab user must see is drawn.

Needs the viewer's Vulkan driver (`.ci/run` installs it: xvfb mesa-vulkan-drivers libvulkan1). Skips, saying why,
where it is missing; in CI (``$CI`` set) it fails instead.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from beambench.cli import app
from beambench.session.viewer import HeadlessViewer, vulkan_available
from beambench.sinks.viewer.spawn import rerun_binary

CONTACT = """
name: lv_contact
rig: contact
sweep: {frequencies: [20, 30]}
settle_s: 1.0
record_s: 1.5
amplitude_mm: 2.0
limits: {max_frequency_hz: 40}
sim: {seed: 3, plate_gap_mm: 1.0}  # the foot reaches the plate within a short run
"""
WALKER = """
name: lv_walker
rig: walker
sweep: {frequencies: [65]}
settle_s: 0.5
record_s: 4.0
amplitude_mm: 2.0
limits: {max_frequency_hz: 80, max_current_a: 6}
sim: {model: prb3, seed: 2, segments: 1}
"""  # walks about 0.5 m: framed on everything seen, the walker ended a speck (0.00 % of the view in leg colour)
MIN_BEAM_FRACTION = 0.003  # of the 3-D view's pixels in colour (the old view: 0.0002 at the contact sweep's 140 s)
MIN_PLATE_FRACTION = 0.005  # brown (the plate's box), of the contact rig's 3-D view


@pytest.fixture(scope="module")
def viewer_ok() -> None:
    problem = None
    if rerun_binary() is None:
        problem = "the rerun viewer binary is missing"
    elif not vulkan_available():
        problem = "no Vulkan driver for the headless Rerun viewer (apt-get install mesa-vulkan-drivers libvulkan1)"
    if problem is not None:
        if os.environ.get("CI"):
            pytest.fail(f"CI must run the real-viewer test: {problem}")
        pytest.skip(problem)


def _run(tmp: Path, name: str, text: str) -> Path:
    proto = tmp / f"{name}.yaml"
    proto.write_text(text)
    res = CliRunner().invoke(app, ["run", str(proto), "--out", str(tmp), "--name", name, "--rerun", "save"])
    assert res.exit_code == 0, res.output
    return tmp / f"{name}.h5"


@pytest.fixture(scope="module")
def sessions(tmp_path_factory, viewer_ok) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("liveview")
    return {"contact": _run(tmp, "c", CONTACT), "walker": _run(tmp, "w", WALKER)}


def _pixels(png: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(float)


def colour_fraction(png: bytes) -> float:
    """Share of pixels in colour (not grey: channel spread > 40 of 255)."""
    a = _pixels(png)
    return float(np.mean(a.max(axis=-1) - a.min(axis=-1) > 40))


def leg_fraction(png: bytes) -> float:
    """Share of the beam's (the legs') yellow pixels, shaded (not the orange tip or the brown plate)."""
    r, g, b = np.moveaxis(_pixels(png), -1, 0)
    return float(np.mean((r > 150) & (g > 0.6 * r) & (g < 0.95 * r) & (b < 0.6 * r)))


def brown_fraction(png: bytes) -> float:
    """Share of brown pixels (the plate, shaded: green 0.45-0.75 of red, little blue; the beam is yellower)."""
    r, g, b = np.moveaxis(_pixels(png), -1, 0)
    return float(np.mean((r > 60) & (g > 0.45 * r) & (g < 0.75 * r) & (b < 0.55 * r)))


def _look(rrd: Path, at: float, shots: Path) -> tuple[dict[str, str], dict, bytes]:
    """Open ``rrd``; the views by name (class), the blueprint and the 3-D view's picture at ``at``."""
    with HeadlessViewer(rrd, window=(1280, 720)) as viewer:
        state = viewer.open()
        assert state.recordings and not state.loading
        spatial = next(v for v in state.views if v.view_class == "3D")
        png = viewer.screenshot(shots / f"{rrd.stem}_3d.png", at=at, view_id=spatial.view_id)
        state = viewer.client.get_state()  # the views' reports after they were drawn
        errors = [(v.name, r.severity, r.summary) for v in state.views for r in v.reports]
        assert not errors, errors  # no view reports a warning or an error
        blueprint = viewer.client.get_blueprint().blueprint
        return {v.name: v.view_class for v in state.views}, blueprint, png


def _time_range_s(blueprint: dict, title: str) -> float:
    """The seconds a time-series panel shows before the cursor."""
    view = next(k for k, v in blueprint.items() if v.get("ViewBlueprint", {}).get("display_name") == title)
    rng = blueprint[f"{view}/VisibleTimeRanges"]["VisibleTimeRanges"]["ranges"]["range"]
    return -rng["start"]["CursorRelative"] * 1e-9


def test_contact_view_shows_the_beam_plate_forces_and_the_step(sessions, tmp_path):
    session = sessions["contact"]
    views, blueprint, png = _look(session.with_suffix(".rrd"), 4.5, tmp_path)
    beam, plate = colour_fraction(png), brown_fraction(png)
    assert beam >= MIN_BEAM_FRACTION, f"3-D view: {100 * beam:.3f} % of pixels in colour"
    assert plate >= MIN_PLATE_FRACTION, f"3-D view: {100 * plate:.3f} % of pixels brown (the plate)"
    names = set(views)
    assert {"Plate normal force (N)", "Plate tangential force (N)", "Motor current (A)"} <= names, names
    assert any("Drive frequency (Hz)" in n for n in names) and views["Step (drive frequency, Hz)"] == "TextDocument"
    assert any(n.startswith("Beam: stage → tip → foot") for n in names)
    assert _time_range_s(blueprint, "Plate normal force (N)") == pytest.approx(2.0)  # forces readable at 2 s
    queries = [str(v["ViewContents"]["query"]) for k, v in blueprint.items() if k.endswith("/ViewContents")]
    assert "/force/normal" in queries, queries  # one quantity per panel; counters and position in none
    assert not [q for q in queries if "sync_edges" in q or "position" in q or q == "/loadcell/**"], queries
    assert blueprint["/time_panel"]["TimePanelBlueprint"]["play_state"] == "Paused"  # a file opens at its start


def test_walker_view_has_no_plate_panels(sessions, tmp_path):
    views, _, png = _look(sessions["walker"].with_suffix(".rrd"), 1.5, tmp_path)
    beam = colour_fraction(png)
    assert beam >= MIN_BEAM_FRACTION, f"3-D view: {100 * beam:.3f} % of pixels in colour"
    names = set(views)
    assert not [n for n in names if "Plate" in n or "Load cell" in n], names
    assert {"Body speed (mm/s)", "Body position (mm)"} <= names and any("Drive frequency (Hz)" in n for n in names)


def test_the_walker_stays_in_view_with_its_legs_as_it_walks_away(sessions, tmp_path):
    """Seen from the frame that follows the body, the walker's legs fill the same share of the 3-D view early,
    midway and at the end of a 0.5 m walk (a speck before: the eye framed the whole walk)."""
    rrd = sessions["walker"].with_suffix(".rrd")
    with HeadlessViewer(rrd, window=(1280, 720)) as viewer:
        state = viewer.open()
        spatial = next(v for v in state.views if v.view_class == "3D")
        legs = [
            leg_fraction(viewer.screenshot(tmp_path / f"walker_{at:g}.png", at=at, view_id=spatial.view_id))
            for at in (0.5, 2.5, 4.4)
        ]
        blueprint = viewer.client.get_blueprint().blueprint
    origin = blueprint[f"/view/{spatial.view_id}"]["ViewBlueprint"]["space_origin"]
    assert origin == "/mocap/follow", origin
    assert min(legs) >= 0.004, legs  # both legs readable (~0.9 % of the view here)
    assert max(legs) <= 1.6 * min(legs), legs  # the same size at every moment


def test_view_screenshot_command_writes_the_viewer_picture(sessions, tmp_path):
    png = tmp_path / "shot.png"
    res = CliRunner().invoke(app, ["view", str(sessions["contact"]), "--screenshot", str(png), "--at", "4.5"])
    assert res.exit_code == 0, res.output
    assert res.stdout.strip() == str(png)
    with Image.open(png) as image:
        size = image.size
    assert size == (1600, 900) and colour_fraction(png.read_bytes()) > 0.01
    outside = CliRunner().invoke(app, ["view", str(sessions["contact"]), "--screenshot", str(png), "--at", "99"])
    assert outside.exit_code == 2 and "outside the session" in outside.stderr


def test_a_viewer_that_cannot_start_is_one_clear_line(sessions, tmp_path, monkeypatch):
    """No usable Vulkan driver (here: pointed at none): one line saying so, exit 2, before any replay."""
    monkeypatch.setenv("VK_ICD_FILENAMES", str(tmp_path / "no_driver.json"))
    res = CliRunner().invoke(app, ["view", str(sessions["contact"]), "--screenshot", str(tmp_path / "x.png")])
    assert res.exit_code == 2, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Vulkan" in lines[0] and "Traceback" not in res.output, res.stderr
    assert not (tmp_path / "x.png").exists()
