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
from beambench.sinks.session_file.reader import read_session
from beambench.sinks.viewer.layout import layout_of

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


def _entities(rrd) -> set[str]:
    """The entity paths the recording logs over time."""
    return {str(chunk.entity_path) for chunk in rc.RrdReader(rrd).stream() if not chunk.is_static}


def _batches(rrd, entity: str) -> list[dict]:
    """The time-varying chunks of ``entity`` in the recording, as column dicts."""
    return [
        chunk.to_record_batch().to_pydict()
        for chunk in rc.RrdReader(rrd).stream()
        if not chunk.is_static and chunk.entity_path == entity
    ]


def _column(batches: list[dict], suffix: str) -> list:
    return [x for b in batches for k, v in b.items() if k.endswith(suffix) for x in v]


def _finished(rrd) -> dict[int, str]:
    """Step number (1-based) → regime or speed text of the step panel's "Last finished" line."""
    texts = _column(_batches(rrd, "/step"), "TextDocument:text")
    found = {}
    for t in texts:
        m = re.search(
            r"Last finished: step (\d+) of \d+ \(index \d+\) at [^:]*: (?:regime|speed) \*\*([^*]+)\*\*", str(t[0])
        )
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
    rrd = touching.with_suffix(".rrd")
    strips = _column(_batches(rrd, "/mocap/beam/foot"), "LineStrips3D:strips")
    assert len(strips) == len(s.streams["mocap"])
    first = np.asarray(strips[0][0], float)
    np.testing.assert_allclose(first, s.streams["mocap"].columns["data"][0] * 1000.0, atol=1e-3)
    entities = _entities(rrd)
    assert "/mocap/beam/foot" in entities and not [
        e for e in entities if "sync_edges" in e or e.endswith("/position") or e.endswith("/seq")
    ]


def test_plate_sits_at_the_foots_contact_height(touching):
    s = read_session(touching)
    boxes = _batches(touching.with_suffix(".rrd"), "/mocap/plate")
    centres = np.asarray([c[0] for c in _column(boxes, "Boxes3D:centers")], float)
    halves = np.asarray([h[0] for h in _column(boxes, "Boxes3D:half_sizes")], float)
    top = centres[-1, 2] + halves[-1, 2]  # sim: z up
    foot_z = s.streams["mocap"].columns["data"][:, 2, 2] * 1000.0
    assert foot_z.min() - 0.5 <= top <= np.median(foot_z), (top, foot_z.min(), np.median(foot_z))


# the physical contact twin at 20 and 25 Hz: foot gaps of exactly a tenth of a drive period (5 and 4 force samples),
# where the contact rule's count turns on the last digit of the frequency and of the window's times
AT_THE_EDGE = """
name: edge
rig: contact
sweep: {frequencies: [20, 25]}
settle_s: 2.0
record_s: 5.0
amplitude_mm: 2.0
limits: {max_frequency_hz: 40}
sim: {model: rod5g, params: physical, twist_deg: 90, noise: true, seed: 0}
"""


def _finished_numbers(rrd) -> dict[int, tuple[str, str]]:
    """Step number (1-based) → (regime, contacts per cycle as shown) of the step panel's "Last finished" line."""
    texts = _column(_batches(rrd, "/step"), "TextDocument:text")
    found = {}
    for t in texts:
        m = re.search(
            r"Last finished: step (\d+) of \d+ \(index \d+\) at [^:]*: regime \*\*([^*]+)\*\* \(([\d.]+) contacts/cycle\)",
            str(t[0]),
        )
        if m:
            found[int(m.group(1))] = (m.group(2), m.group(3))
    return found


def test_step_panel_contacts_per_cycle_are_the_reports_live_and_replayed(tmp_path):
    """The live panel's contacts per cycle is the report's (steps.csv) for every step: the analysis's own
    computation on the same window (it read 0.07 and 0.52 where the report has 0.14 and 0.59 here)."""
    proto = tmp_path / "edge.yaml"
    proto.write_text(AT_THE_EDGE)
    res = CliRunner().invoke(app, ["run", str(proto), "--out", str(tmp_path), "--name", "e", "--rerun", "save"])
    assert res.exit_code == 0, res.output
    session = tmp_path / "e.h5"
    table = analyze_session(read_session(session)).table
    expected = {i + 1: (str(r.regime), f"{r.contacts_per_cycle:.2f}") for i, r in enumerate(table.itertuples())}
    assert all(float(n) > 0 for _, n in expected.values()), expected  # contacts to count
    assert _finished_numbers(session.with_suffix(".rrd")) == expected  # the run's own recording (live order)
    replayed = replay_session(session, "save", tmp_path / "replay.rrd")
    assert replayed is not None and _finished_numbers(replayed) == expected


def test_the_step_panel_shows_the_measured_frequency_of_the_step_in_sight(touching):
    """At a step's start the panel says "settling", never the last step's speed beside the new command; once
    half a second of the step exists, the measured frequency is this step's own (within 2 % of the command by
    the step's end); after the last step, the panel says it ended (motor samples stamped after the end do not
    bring the running step back)."""
    batches = _batches(touching.with_suffix(".rrd"), "/step")
    texts = [str(t[0]) for t in _column(batches, "TextDocument:text")]
    times = np.asarray(_column(batches, "session_time"), "timedelta64[ns]").astype(np.int64)
    last = texts[max(range(len(texts)), key=lambda i: (times[i], i))]  # what the viewer shows at the end
    assert "Between steps" in last and "Last finished: step 2" in last, last
    by_step: dict[int, list[str]] = {}
    for text in texts:
        m = re.search(r"## Step (\d+) of", text)
        if m and "measured" in text:
            by_step.setdefault(int(m.group(1)), []).append(text)
    assert set(by_step) == {1, 2}, by_step
    for step, shown in by_step.items():
        assert "measured: settling" in shown[0], shown[0]  # the new command, nothing from the step before
        m = re.search(r"commanded ([\d.]+) Hz · measured ([\d.]+) Hz", shown[-1])
        assert m, shown[-1]
        commanded, measured = float(m.group(1)), float(m.group(2))
        assert abs(measured - commanded) <= 0.02 * commanded, (step, shown[-1])


def test_step_panel_regimes_are_the_analysis_regimes_live_and_replayed(touching, tmp_path):
    table = analyze_session(read_session(touching)).table
    expected = {i + 1: str(r) for i, r in enumerate(table["regime"])}
    assert set(expected.values()) - {"none"}, expected  # the test needs contacts to compare
    assert _finished(touching.with_suffix(".rrd")) == expected  # the run's own recording (live order)
    replayed = replay_session(touching, "save", tmp_path / "replay.rrd")
    assert replayed is not None and _finished(replayed) == expected
