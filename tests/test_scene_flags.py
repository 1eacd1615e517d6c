"""A rig is what its scene's catalogue entry says, never its name: a scene declared here (as a new scene module's
declaration line would) gets the report figures, the per-step table, the captions and the live-view layout its
flags call for, and a rig named like a shipped one but flagged otherwise does not inherit that one's treatment."""

from __future__ import annotations

import contextlib

import pytest
from typer.testing import CliRunner

from beambench.acquisition.protocol import scenes
from beambench.acquisition.protocol.scenes import SceneInfo
from beambench.acquisition.streams import loadcell_spec, mocap_spec, motor_spec
from beambench.analysis.figures import FIGURES
from beambench.analysis.synthetic import SynthSession, SynthStep, write_synthetic_session
from beambench.cli import app
from beambench.sinks.viewer.layout import layout_of
from beambench.studies.sweep.figure import sweep_title
from beambench.studies.sweep.run import SweepSpec

PLATE_FIGURES = {"contact_frequency", "drift", "forces", "contact_direction"}
WALKING_FIGURES = {"walking_speed", "body_trajectory", "gait", "tracking"}
DRIVEN_FIGURES = {"trajectories", "ellipse", "frequency"}


@pytest.fixture
def declare():
    """Declare a scene in the catalogue for one test (the catalogue is process-wide: it is put back after)."""
    with contextlib.ExitStack() as undo:

        def add(info: SceneInfo) -> SceneInfo:
            assert info.name not in scenes.SCENES
            undo.enter_context(scenes.SCENES.restoring(info.name))
            return scenes.declare(info)

        yield add


def _figures(rig: str) -> set[str]:
    return {spec.key for spec in FIGURES.for_rigs({rig})}


def test_a_new_scene_gets_the_figures_its_flags_call_for(declare):
    declare(SceneInfo("bench2", "a second plate rig", markers=("stage", "tip", "foot"), plate=True, stage=True))
    declare(SceneInfo("hopper", "a one-legged walker", markers=("hub", "foot_left"), body_marker="hub"))
    declare(SceneInfo("pluck", "a plucked beam", markers=("stage", "tip1"), driven=False, free_decay=True))
    declare(SceneInfo("shaker", "a shaken beam, nothing under it", markers=("stage", "tip"), stage=True))
    assert _figures("bench2") == PLATE_FIGURES | DRIVEN_FIGURES | {"sync"}
    assert _figures("hopper") == WALKING_FIGURES | DRIVEN_FIGURES | {"sync"}
    assert _figures("pluck") == {"release_decay", "sync"}
    assert _figures("shaker") == DRIVEN_FIGURES | {"sync"}
    assert _figures("hopper") == _figures("walker") and _figures("pluck") == _figures("release")
    # a compare of a new walker with the shipped contact rig draws what both have
    assert {s.key for s in FIGURES.for_rigs({"hopper", "contact"})} == DRIVEN_FIGURES | {"sync"}
    assert "hopper" in FIGURES["gait"].rigs and "hopper" not in FIGURES["forces"].rigs
    assert "relative to the body" in FIGURES["trajectories"].caption_for("hopper")
    assert "relative to the stage" in FIGURES["trajectories"].caption_for("shaker")


def test_a_rig_the_catalogue_does_not_know_gets_the_figures_of_any_rig_only():
    assert _figures("treadmill") == set()  # every figure but none: "sync" applies to every *known* rig
    assert FIGURES.for_rigs({"treadmill", "contact"}) == []


def test_a_new_walking_scenes_session_is_reported_as_a_walker(declare, tmp_path):
    """A synthetic session on a newly declared walking rig: its report has the walking figures and the body-speed
    table, and no plate figure or contact note (the synthetic walker's markers: its body, here called hub, and both
    feet: the analysis finds the body by the scene's name for it)."""
    declare(SceneInfo("strider", "a new walker", markers=("hub", "foot_left", "foot_right"), body_marker="hub"))
    session = write_synthetic_session(
        tmp_path / "strider.h5",
        SynthSession(
            [SynthStep(23.0, 0, body_speed_mm_s=-35.0), SynthStep(65.0, 0, body_speed_mm_s=150.0)],
            rig="strider",
            record_s=1.0,
            settle_s=0.3,
            seed=4,
        ),
    )
    out = tmp_path / "report"
    figures = "walking_speed,trajectories"
    res = CliRunner().invoke(
        app, ["analyze", str(session), "--out", str(out), "--no-write", "-q", "--figures", figures]
    )
    assert res.exit_code == 0, res.output
    assert {p.stem for p in out.glob("*.png")} == {"walking_speed", "trajectories"}
    res = CliRunner().invoke(
        app, ["analyze", str(session), "--out", str(out), "--no-write", "-q", "--figures", "forces"]
    )
    assert res.exit_code == 2 and "not drawn for strider sessions" in res.output
    html = (out / "index.html").read_text()
    assert "body speed (mm/s)" in html and "left foot ellipse major (mm)" in html
    assert "Both feet relative to the body" in html and "No touchdown" not in html


def test_the_live_view_finds_a_walkers_body_from_its_scene_not_a_marker_name(declare):
    declare(SceneInfo("hopper", "a walker whose body marker is the hub", markers=("hub", "foot"), body_marker="hub"))
    declare(SceneInfo("bodied", "a plate rig with a marker called body", markers=("body", "foot"), plate=True))
    hopper = layout_of([mocap_spec(("hub", "foot")), loadcell_spec(), motor_spec()], "hopper")
    assert hopper.body == "hub" and hopper.chains == (("hub", "foot"),) and not hopper.plate
    bodied = layout_of([mocap_spec(("body", "foot")), loadcell_spec(), motor_spec()], "bodied")
    assert bodied.body is None and bodied.chains == (("body", "foot"),) and bodied.plate


def test_the_sweep_chart_shows_the_foot_only_where_the_scene_has_a_plate(declare):
    """A sweepable scene with nothing under the beam charts its tip; one with a plate under the foot, the foot."""
    declare(SceneInfo("shaker", "a shaken beam, nothing under it", markers=("stage", "tip"), stage=True, batched=True))
    declare(SceneInfo("bench2", "a second plate rig", markers=("stage", "foot"), plate=True, stage=True, batched=True))
    shaker = SweepSpec.model_construct(**{**SweepSpec().model_dump(), "name": "s", "scene": "shaker"})
    assert sweep_title(shaker, ["twist_deg"]).startswith("s: tip path ellipse vs twist angle")
    bench = shaker.model_copy(update={"scene": "bench2"})
    assert sweep_title(bench, ["twist_deg"]).startswith("s: foot path relative to the stage ellipse")
