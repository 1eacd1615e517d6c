"""The Rerun sink on its own, saving to a real ``.rrd`` read back with Rerun's own reader."""

from __future__ import annotations

import numpy as np
import rerun.chunk as rc

from beambench.acquisition.batch import Batch, ColumnSpec, StreamSpec
from beambench.sinks.viewer.sink import SAVE_CHUNK_SECONDS, RerunSink

MOTOR = StreamSpec("motor", 100.0, {"velocity": ColumnSpec(unit="turn/s", plotted=True)})


def test_a_slow_stream_is_sent_at_least_every_chunk_span_of_session_time(tmp_path):
    """100 Hz telemetry fills 2 MiB only after ~20 min: its columns must not wait (in memory, lost to a kill)
    longer than ``SAVE_CHUNK_SECONDS`` of session time, and nothing may be lost or repeated."""
    rrd = tmp_path / "slow.rrd"
    sink = RerunSink("save", "slow", rrd, t0_ns=0)
    sink.open([MOTOR])
    span_s, per_batch = 3.5 * SAVE_CHUNK_SECONDS, 10  # 0.1 s batches of 10 rows at 100 Hz
    n = int(span_s * 100)
    t_ns = np.arange(n, dtype=np.int64) * 10_000_000
    v = np.sin(np.arange(n) * 0.01)
    for i in range(0, n, per_batch):
        sl = slice(i, i + per_batch)
        sink.write(Batch("motor", t_ns[sl], t_ns[sl] * 1e-9, {"velocity": v[sl]}))
    sink.close()
    spans, values = [], []
    for chunk in rc.RrdReader(rrd).stream():
        if chunk.entity_path == "/motor/velocity" and not chunk.is_static:
            batch = chunk.to_record_batch().to_pydict()
            times = [c for c in batch if "session_time" in c]
            t = np.asarray(batch[times[0]], dtype="timedelta64[ns]").astype(np.int64) * 1e-9
            spans.append(t.max() - t.min())
            values.extend(np.concatenate([np.asarray(x) for x in batch["Scalars:scalars"]]))
    assert len(spans) >= 3, spans  # 3.5 spans of data: at least 3 chunks (one, before the bound)
    assert max(spans) <= SAVE_CHUNK_SECONDS + 0.1
    np.testing.assert_allclose(np.sort(values), np.sort(v))


def test_a_speed_tracking_run_shows_target_measured_and_commanded_in_the_live_view(tmp_path):
    """A run with the speed controller's stream gets its panels, and its columns reach the recording (the
    controller's band, mode and integrator do not: they are not what a panel plots)."""
    from beambench.acquisition.control.speed_controller import track_spec
    from beambench.sinks.viewer.layout import layout_of

    spec = track_spec(0.1)
    layout = layout_of([MOTOR, spec], rig="walker")
    titles = [p.title for p in layout.panels]
    assert any("Speed tracking" in t for t in titles) and any("Commanded drive frequency" in t for t in titles)
    assert not any("Speed tracking" in p.title for p in layout_of([MOTOR], rig="walker").panels)
    rrd = tmp_path / "track.rrd"
    sink = RerunSink("save", "track", rrd, t0_ns=0)
    sink.open([MOTOR, spec])
    n = 50
    t_ns = np.arange(n, dtype=np.int64) * 100_000_000
    cols = {name: np.full(n, 1.0 + i, dtype=c.dtype) for i, (name, c) in enumerate(spec.columns.items())}
    sink.write(Batch("track", t_ns, t_ns * 1e-9, cols))
    sink.close()
    entities = {chunk.entity_path for chunk in rc.RrdReader(rrd).stream() if not chunk.is_static}
    assert {"/track/target_mm_s", "/track/measured_mm_s", "/track/frequency_hz"} <= entities
    assert "/track/mode" not in entities and "/track/integral_mm_s" not in entities


def _walker_mocap() -> StreamSpec:
    from beambench.acquisition.batch import Frame

    labels = ("body", "foot_left", "foot_right")
    return StreamSpec(
        "mocap",
        360.0,
        {"data": ColumnSpec((3, 3), unit="m", labels=labels)},
        frame=Frame(up_axis="z", forward_axis="x"),
    )


def _collapsing_walk(n: int = 3600) -> tuple[np.ndarray, np.ndarray]:
    """10 s of a walker that folds its legs and sinks through the floor while it walks 1.5 m forward (m)."""
    t = np.arange(n) / 360.0
    x = 0.15 * t + 0.004 * np.sin(2 * np.pi * 20 * t)  # 150 mm/s, swinging ±4 mm at the drive frequency
    sink_z = np.clip(0.03 - 0.01 * t, -0.04, None)  # the body from 30 mm above the floor to 40 mm below it
    body = np.stack([x, np.zeros(n), sink_z], 1)
    left = np.stack([x + 0.02 * np.sin(40 * t), np.full(n, 0.05), np.zeros(n)], 1)
    right = np.stack([x, np.full(n, -0.05), np.zeros(n)], 1)
    return t, np.stack([body, left, right], 1)


def _follow_frame(rrd) -> tuple[np.ndarray, np.ndarray]:
    """The walker view's frame as the recording holds it: times (s) and translations (mm) of /mocap/follow."""
    times, values = [], []
    for chunk in rc.RrdReader(rrd).stream():
        if chunk.entity_path == "/mocap/follow" and not chunk.is_static:
            batch = chunk.to_record_batch().to_pydict()
            times.append(np.asarray(batch["session_time"], "timedelta64[ns]").astype(np.int64) * 1e-9)
            values.append(np.asarray([v[0] for v in batch["Transform3D:translation"]], float))
    assert times, "no /mocap/follow transform in the recording"
    t, v = np.concatenate(times), np.concatenate(values)
    order = np.argsort(t, kind="stable")
    return t[order], v[order]


def _framings(rrd) -> list[dict]:
    """Each blueprint the recording holds, in the order sent: its 3-D view's eye (``position``, ``look_target``,
    mm), ``origin`` and whether its ``grid`` is drawn."""
    reader = rc.RrdReader(rrd)
    found = []
    for store in reader.blueprints():
        views: dict[str, dict] = {}
        sent = None
        for chunk in reader.stream(store=store):
            rows = chunk.to_record_batch().to_pydict()
            if "log_time" in rows:
                first = min(rows["log_time"])
                sent = first if sent is None else min(sent, first)
            view, _, part = chunk.entity_path.removeprefix("/view/").partition("/")
            if not chunk.entity_path.startswith("/view/"):
                continue
            fields = views.setdefault(view, {})
            if part == "EyeControls3D":
                fields["position"] = np.asarray(rows["EyeControls3D:position"][0][0], float)
                fields["look_target"] = np.asarray(rows["EyeControls3D:look_target"][0][0], float)
            elif part == "LineGrid3D":
                fields["grid"] = bool(rows["LineGrid3D:visible"][0][0])
            elif not part and rows.get("ViewBlueprint:class_identifier") == [["3D"]]:
                fields["origin"] = rows["ViewBlueprint:space_origin"][0][0]
        spatial = [v for v in views.values() if "origin" in v]
        assert len(spatial) == 1, views  # one 3-D view a blueprint
        found.append((sent, spatial[0]))
    return [framing for _, framing in sorted(found, key=lambda x: x[0])]


def test_the_walker_view_follows_the_body_and_its_eye_sees_all_of_it_whatever_the_body_does(tmp_path):
    """A body that walks 1.5 m while it sinks below the floor with folded legs: the view's frame (read back from
    the recording) follows the body over the floor, so seen from it every marker stays in one small box, framed
    on the walker alone; the eye stays outside that box and sees all of it; a fall through the floor is not followed."""
    from beambench.sinks.viewer.scene import EYE_DISTANCE, MIN_EXTENT_MM

    rrd = tmp_path / "walk.rrd"
    sink = RerunSink("save", "walk", rrd, t0_ns=0, rig="walker")
    sink.open([_walker_mocap()])
    t, pos = _collapsing_walk()
    for i in range(0, len(t), 180):  # 0.5 s batches
        sl = slice(i, i + 180)
        t_ns = (t[sl] * 1e9).astype(np.int64)
        sink.write(Batch("mocap", t_ns, t[sl], {"data": pos[sl]}))
    sink.close()
    ft, follow = _follow_frame(rrd)
    k = np.searchsorted(ft, t + 1e-9, side="right") - 1  # the frame in force at each mocap frame (latest at)
    assert np.all(k >= 0)
    rel = pos * 1e3 - follow[k][:, None, :]
    assert np.ptp(pos[:, 0, 0]) * 1e3 > 1400  # the walker walked away ...
    assert np.ptp(rel[:, :, 0]) < 120 and np.ptp(rel[:, :, 1]) < 110  # ... and stays in view, legs and all
    assert np.allclose(follow[:, 2], 0.0)  # over the floor only: the sinking body is not followed down
    framings = _framings(rrd)  # the eye is placed EYE_DISTANCE × the framed box's diagonal (at least the minimum)
    diagonals = [np.linalg.norm(f["position"] - f["look_target"]) / EYE_DISTANCE for f in framings]
    assert framings and max(diagonals) <= MIN_EXTENT_MM[True] + 1e-3, diagonals  # framed on the walker, not the walk
    points_mm = rel.reshape(-1, 3)
    lo, hi = points_mm.min(axis=0), points_mm.max(axis=0)  # the box the walker filled in the view's frame
    last = framings[-1]
    eye, target = last["position"], last["look_target"]
    assert np.all(target >= lo) and np.all(target <= hi)  # aimed into the walker's box ...
    assert np.any(eye < lo) or np.any(eye > hi)  # ... from outside it
    axis = (target - eye) / np.linalg.norm(target - eye)
    rays = (points_mm - eye) / np.linalg.norm(points_mm - eye, axis=1, keepdims=True)
    assert np.degrees(np.arccos(np.clip(rays @ axis, -1, 1))).max() < 30  # all of it inside a 60° view cone
    assert all(f["origin"] == "/mocap/follow" and not f["grid"] for f in framings)  # the follow frame, its own floor


def test_the_step_panel_tells_a_standstill_from_a_walk():
    """ "+0.0 mm/s" alone reads as a broken number: the panel says the body swings in place, walking nowhere."""
    import rerun as rr

    from beambench.acquisition.batch import StepRecord
    from beambench.sinks.viewer.step import StepPanel

    panel = StepPanel(rr.RecordingStream("step-test"), 2, t0_ns=0)
    t = np.arange(0, 3, 1 / 360)
    for index, speed in ((0, 0.0), (1, 20.0)):
        t0 = 3.0 * index
        panel.step(StepRecord(index, 50.0, int(t0 * 1e9)), t0)
        panel.body(((t0 + t) * 1e9).astype(np.int64), speed * t + 4.0 * np.sin(2 * np.pi * 50 * t))
        panel.step(StepRecord(index, 50.0, int(t0 * 1e9), int(t0 * 1e9), int((t0 + 3) * 1e9), status="done"), t0 + 3)
        if index == 0:
            assert "+0.0 mm/s**: no net walking (the body swings ±4 mm in place)" in panel.last_done
    assert "+20.0 mm/s** (the body swings ±4 mm about that)" in panel.last_done


def test_a_stream_the_layout_does_not_know_is_shown_by_what_its_spec_marks_plotted(tmp_path):
    """No entry per stream in the sinks: a plotted column goes to ``<stream>/<label>`` with a panel of its own
    (title from the descriptions and the unit); a column not marked plotted stays in the session file only."""
    from beambench.sinks.viewer.layout import layout_of

    imu = StreamSpec(
        "imu",
        200.0,
        {
            "acc": ColumnSpec((2,), "float64", "m/s²", ("ax", "ay"), "acceleration", plotted=True),
            "temp": ColumnSpec((), "float64", "°C", (), "die temperature"),
        },
        description="tip IMU",
    )
    layout = layout_of([MOTOR, imu], "contact")
    (panel,) = [p for p in layout.panels if any(s.entity.startswith("imu/") for s in p.series)]
    assert panel.title == "tip IMU: acceleration (m/s²)"
    assert [s.entity for s in panel.series] == ["imu/ax", "imu/ay"]
    rrd = tmp_path / "imu.rrd"
    sink = RerunSink("save", "imu", rrd, t0_ns=0)
    sink.open([imu])
    n = 50
    t_ns = np.arange(n, dtype=np.int64) * 5_000_000
    sink.write(Batch("imu", t_ns, t_ns * 1e-9, {"acc": np.ones((n, 2)), "temp": np.full(n, 30.0)}))
    sink.close()
    rows: dict[str, int] = {}
    for chunk in rc.RrdReader(rrd).stream():
        if not chunk.is_static:
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    assert rows.get("/imu/ax") == rows.get("/imu/ay") == n
    assert not any(e.startswith("/imu/temp") for e in rows)
