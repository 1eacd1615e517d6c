"""The scene registry: every declared scene is buildable or sweepable as it says, and what the rest of the code
reads from it (rig names, markers, another scene's options) is what it was before the registry."""

from __future__ import annotations

import pytest

from beambench.acquisition.protocol import scenes as catalogue
from beambench.acquisition.protocol.schema import parse_protocol
from beambench.acquisition.streams import CONTACT_MARKERS, WALKER_MARKERS
from beambench.common.yaml_config import ConfigError
from beambench.sim import scenes


def test_every_runnable_scene_has_a_builder_and_every_batched_one_a_sweep_runner():
    assert catalogue.runnable_names() == ("contact", "walker", "release")
    assert catalogue.batched_names() == ("free_beam", "contact")
    for name in catalogue.runnable_names():
        assert scenes.get(name).info is catalogue.scene_info(name)
    assert set(scenes.batched_scenes()) == set(
        catalogue.batched_names()
    )  # each engine registered in its scene's module
    with pytest.raises(KeyError, match="no builder"):
        scenes.get("free_beam")
    with pytest.raises(KeyError, match="'walker' has no batched engine"):
        scenes.batch_engine("walker")
    with pytest.raises(KeyError, match="scene 'boat' is not declared \\(declared: free_beam, contact"):
        catalogue.scene_info("boat")


def test_markers_and_wiring_are_the_scenes_own():
    assert CONTACT_MARKERS == ("stage", "tip", "foot")
    assert WALKER_MARKERS == ("body", "foot_left", "foot_right")
    release = catalogue.scene_info("release")
    assert release.markers == ("stage", "tip1", "tip2", "tip3")
    assert release.wired_markers == CONTACT_MARKERS  # the bench's release test is wired like the contact rig
    assert catalogue.scene_info("walker").wired_markers == WALKER_MARKERS


def test_another_scenes_option_is_refused_with_the_scene_that_takes_it():
    assert catalogue.foreign_option("contact", {"plate_gap_mm", "tolerance_mm", "model"}, "rig") is None
    option, reason = catalogue.foreign_option("walker", {"model", "tolerance_mm", "plate_gap_mm"}, "rig")
    assert option == "plate_gap_mm" and reason == "applies to rig: contact only (the walker scene has no plate)"
    option, reason = catalogue.foreign_option("release", {"segments"}, "rig")
    assert (option, reason) == (
        "segments",
        "applies to rig: contact or walker only (the release scene does not settle into a steady gait)",
    )


def test_a_scene_is_declared_once():
    with pytest.raises(ValueError, match="declared twice"):
        catalogue.declare(catalogue.SceneInfo("contact", "again"))


def test_the_protocols_rig_is_checked_against_the_catalogue():
    text = "sweep: {frequencies: [0]}\nrig: %s\n"
    assert parse_protocol(text % "release").rig == "release"  # the one scene that is not driven
    with pytest.raises(ConfigError, match=r"frequencies must be > 0 Hz on the contact rig \(0 is for rig: release\)"):
        parse_protocol(text % "contact")
    with pytest.raises(ConfigError, match="Input should be 'contact', 'walker' or 'release'"):
        parse_protocol(text % "free_beam")  # a sweep-only scene is no rig


def test_a_sweep_task_is_a_typed_frozen_value_that_pickles():
    """Workers receive a SweepTask of Jobs (not a dict of tuples): a misspelt field fails where it is made."""
    import dataclasses
    import pickle

    from beambench.studies.sweep.run import SweepSpec, make_tasks, plan
    from beambench.studies.sweep.task import Job, SweepTask

    spec = SweepSpec.model_validate({"scene": "contact", "points": [{"gap_mm": 1.0}], "frequencies": [5, 10]})
    tasks = make_tasks(spec, plan(spec), 1)
    assert [type(t) for t in tasks] == [SweepTask, SweepTask]
    assert all(isinstance(j, Job) for t in tasks for j in t.jobs)
    assert pickle.loads(pickle.dumps(tasks[0])) == tasks[0]
    assert dataclasses.is_dataclass(tasks[0]) and tasks[0].scene == "contact"
