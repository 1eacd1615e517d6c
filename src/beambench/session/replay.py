"""Replay a recorded session into the Rerun viewer (or an ``.rrd`` file), as the run sent it live.

The streams go out interleaved in windows of :data:`WINDOW_S` of session time, split at each step's start and
end (a step's record and the events at a window's start, then every stream's slice of the window), so the view
is built in the order the run saw it: the plate's height from the contacts, the step panel with each step's
regime or speed from the data before its end and no data from after a step's start in its first line.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from beambench.acquisition.batch import Batch, StepRecord
from beambench.analysis.session_analysis import session_calibration, session_rig
from beambench.analysis.step_contacts import window_contacts
from beambench.sinks.session_file.reader import SessionFile, read_session
from beambench.sinks.viewer import RerunMode
from beambench.sinks.viewer.sink import RerunSink

WINDOW_S = 1.0


def replay_session(session_path: Path, mode: RerunMode, out: Path | None = None) -> Path | None:
    """Send a recorded session to Rerun in ~1 s batches; returns the .rrd path in save mode (``out``, default
    ``<session>_view.rrd`` beside the session: never the ``.rrd`` that ``run`` saved)."""

    session = read_session(session_path)
    rrd = (out or session_path.with_name(f"{session_path.stem}_view.rrd")) if mode == "save" else None
    starts = [int(s.host_time_ns[0]) for s in session.streams.values() if len(s)]
    ends = [int(s.host_time_ns[-1]) for s in session.streams.values() if len(s)]
    if len(session.steps):
        starts.append(int(session.steps["t_start_ns"].min()))
    t0 = min(starts, default=0)
    sink = RerunSink(
        mode,
        session_path.stem,
        rrd,
        t0_ns=t0,
        calibration=session_calibration(session.general),
        rig=session_rig(session.general),
        total_steps=len(session.steps) or None,
        step_contacts=window_contacts,
    )
    sink.open([s.spec for s in session.streams.values()])
    steps = _step_records(session)
    events = sorted(zip(session.events.host_time_ns, session.events.kind, session.events.message), key=lambda e: e[0])
    window = int(WINDOW_S * 1e9)
    grid = np.arange(t0, max(ends, default=t0) + window + 1, window, dtype=np.int64)
    at_steps = np.asarray([t for t, _ in steps if t0 <= t <= grid[-1]], dtype=np.int64)
    edges = np.unique(np.concatenate([grid, at_steps]))  # steps split the windows
    cursor = {name: 0 for name in session.streams}
    for w0, w1 in itertools.pairwise(edges):
        while steps and steps[0][0] <= w0:  # a step that starts (or ends) here, before the data after it
            sink.step(steps.pop(0)[1])
        while events and events[0][0] <= w0:
            t_ns, kind, message = events.pop(0)
            sink.event(int(t_ns), str(kind), str(message))
        for name, s in session.streams.items():
            i, j = cursor[name], int(np.searchsorted(s.host_time_ns, w1, side="left"))
            if j > i:
                cols = {k: v[i:j] for k, v in s.columns.items()}
                sink.write(Batch(name, s.host_time_ns[i:j], s.device_time[i:j], cols))
            cursor[name] = j
    for _, record in steps:  # any step time past the streams' end
        sink.step(record)
    for t_ns, kind, message in events:
        sink.event(int(t_ns), str(kind), str(message))
    sink.close()
    return rrd


def _step_records(session: SessionFile) -> list[tuple[int, StepRecord]]:
    """Each step's start (as ``running``) and end (with its final status), in time order."""
    out: list[tuple[int, StepRecord]] = []
    for row in session.steps.to_dict("records"):
        index, freq, start = int(row["index"]), float(row["frequency_hz"]), int(row["t_start_ns"])
        out.append((start, StepRecord(index, freq, start)))
        if int(row["t_end_ns"]) >= 0:
            settled, end_ns = int(row["t_settled_ns"]), int(row["t_end_ns"])
            out.append((end_ns, StepRecord(index, freq, start, settled, end_ns, str(row["status"]))))
    out.sort(key=lambda x: x[0])
    return out
