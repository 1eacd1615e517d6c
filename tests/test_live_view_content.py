"""What the live view logs, read back from the ``.rrd`` with Rerun's own reader (no viewer needed): the layout per
rig from the streams' specs, the beam strips, the plate at the foot's contact height, and a step panel whose
regimes are the analysis's."""

from __future__ import annotations

import re

import numpy as np
import pytest
import rerun.chunk as rc
from typer.testing import CliRunner

from beambench.acquisition.streams import CONTACT_MARKERS, WALKER_MARKERS, loadcell_spec, mocap_spec, motor_spec
from beambench.analysis.session_analysis import analyze_session
from beambench.cli import app
from beambench.session.replay import replay_session
from beambench.sinks.hdf5 import read_session
from beambench.sinks.rerun_layout import layout_of

# a 1 mm gap: the foot reaches the plate within a short run (regimes 1 and 1/2)
TOUCHING = """
name: touching
rig: contact
sweep: {frequencies: [20, 30]}
settle_s: 1.0
record_s: 1.5
amplitude_mm: 2.0
limits: {max_frequency_hz: 40}
sim: {seed: 3, plate_gap_mm: 1.0}
"""


@pytest.fixture(scope="module")
def touching(tmp_path_factory):
    out = tmp_path_factory.mktemp("touching")
    proto = out / "t.yaml"
    proto.write_text(TOUCHING)
    res = CliRunner().invoke(app, ["run", str(proto), "--out", str(out), "--name", "t", "--rerun", "save"])
    assert res.exit_code == 0, res.output
    return out / "t.h5"


def _chunks(rrd) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for chunk in rc.RrdReader(rrd).stream():
        if not chunk.is_static:
            out.setdefault(chunk.entity_path, []).append(chunk.to_record_batch().to_pydict())
    return out


def _column(batches: list[dict], suffix: str) -> list:
    return [x for b in batches for k, v in b.items() if k.endswith(suffix) for x in v]


def _finished(rrd) -> dict[int, str]:
    """Step number (1-based) → regime or speed text of the step panel's "Last finished" line."""
    texts = _column(_chunks(rrd)["/step"], "TextDocument:text")
    found = {}
    for t in texts:
        m = re.search(r"Last finished: step (\d+) \([^)]*\): (?:regime|speed) \*\*([^*]+)\*\*", str(t[0]))
        if m:
            found[int(m.group(1))] = m.group(2)
    return found


def test_layout_comes_from_the_streams_and_the_rig():
    contact = layout_of([mocap_spec(CONTACT_MARKERS), loadcell_spec(), motor_spec()], "contact")
    assert contact.chains == (("stage", "tip", "foot"),) and contact.plate and contact.body is None
    titles = [p.title for p in contact.panels]
    assert "Plate normal force (N)" in titles and "Plate tangential force (N)" in titles
    walker = layout_of([mocap_spec(WALKER_MARKERS), loadcell_spec(), motor_spec()], "walker")  # the sim streams both
    assert walker.chains == (("body", "foot_left"), ("body", "foot_right")) and not walker.plate
    assert walker.loadcell_panel is None and not [p for p in walker.panels if "force" in p.title.lower()]
    assert {"Body speed (mm/s)", "Body position (mm)"} <= {p.title for p in walker.panels}
    assert not walker.logged("loadcell", "data") and not contact.logged("loadcell", "sync_edges")
    assert not contact.logged("motor", "position") and contact.logged("motor", "velocity")


def test_beam_strips_are_the_markers_in_mm(touching):
    s = read_session(touching)
    chunks = _chunks(touching.with_suffix(".rrd"))
    strips = _column(chunks["/mocap/beam/foot"], "LineStrips3D:strips")
    assert len(strips) == len(s.streams["mocap"])
    first = np.asarray(strips[0][0], float)
    np.testing.assert_allclose(first, s.streams["mocap"].columns["data"][0] * 1000.0, atol=1e-3)
    assert not [e for e in chunks if "sync_edges" in e or e.endswith("/position") or e.endswith("/seq")]


def test_plate_sits_at_the_foots_contact_height(touching):
    s = read_session(touching)
    boxes = _chunks(touching.with_suffix(".rrd"))["/mocap/plate"]
    centres = np.asarray([c[0] for c in _column(boxes, "Boxes3D:centers")], float)
    halves = np.asarray([h[0] for h in _column(boxes, "Boxes3D:half_sizes")], float)
    top = centres[-1, 2] + halves[-1, 2]  # sim: z up
    foot_z = s.streams["mocap"].columns["data"][:, 2, 2] * 1000.0
    assert foot_z.min() - 0.5 <= top <= np.median(foot_z), (top, foot_z.min(), np.median(foot_z))


def test_step_panel_regimes_are_the_analysis_regimes_live_and_replayed(touching, tmp_path):
    table = analyze_session(read_session(touching)).table
    expected = {i + 1: str(r) for i, r in enumerate(table["regime"])}
    assert set(expected.values()) - {"none"}, expected  # the test needs contacts to compare
    assert _finished(touching.with_suffix(".rrd")) == expected  # the run's own recording (live order)
    replayed = replay_session(touching, "save", tmp_path / "replay.rrd")
    assert replayed is not None and _finished(replayed) == expected
