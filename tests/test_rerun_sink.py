"""The Rerun sink on its own, saving to a real ``.rrd`` read back with Rerun's own reader."""

from __future__ import annotations

import numpy as np
import rerun.chunk as rc

from beambench.acquisition.batch import Batch, ColumnSpec, StreamSpec
from beambench.sinks.rerun_view import SAVE_CHUNK_SECONDS, RerunSink

MOTOR = StreamSpec("motor", 100.0, {"velocity": ColumnSpec(unit="turn/s")})


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
    from beambench.acquisition.tracking import track_spec
    from beambench.sinks.rerun_layout import layout_of

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
