"""Replay a recorded session into the Rerun viewer (or an ``.rrd`` file)."""

from __future__ import annotations

from pathlib import Path

from beambench.acquisition.batch import Batch
from beambench.sinks import RerunMode
from beambench.sinks.hdf5 import read_session
from beambench.sinks.rerun_view import RerunSink


def replay_session(session_path: Path, mode: RerunMode, out: Path | None = None) -> Path | None:
    """Send a recorded session to Rerun in ~1 s batches; returns the .rrd path in save mode."""

    session = read_session(session_path)
    rrd = (out or session_path.with_suffix(".rrd")) if mode == "save" else None
    t0 = min((int(s.host_time_ns[0]) for s in session.streams.values() if len(s)), default=0)
    sink = RerunSink(mode, session_path.stem, rrd, t0_ns=t0)
    sink.open([s.spec for s in session.streams.values()])
    for name, s in session.streams.items():
        step = max(1, int(s.spec.rate_hz) or 1000)
        for i in range(0, len(s), step):
            sl = slice(i, i + step)
            sink.write(Batch(name, s.host_time_ns[sl], s.device_time[sl], {k: v[sl] for k, v in s.columns.items()}))
    for row in session.events.itertuples():
        sink.event(int(row.host_time_ns), row.kind, row.message)
    sink.close()
    return rrd
