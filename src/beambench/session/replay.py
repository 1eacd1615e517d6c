"""Replay a recorded session into the Rerun viewer (or an ``.rrd`` file)."""

from __future__ import annotations

from pathlib import Path

from beambench.acquisition.batch import Batch
from beambench.analysis.session import session_calibration
from beambench.sinks import RerunMode
from beambench.sinks.hdf5 import read_session
from beambench.sinks.rerun_view import RerunSink


def replay_session(session_path: Path, mode: RerunMode, out: Path | None = None) -> Path | None:
    """Send a recorded session to Rerun in ~1 s batches; returns the .rrd path in save mode (``out``, default
    ``<session>_view.rrd`` beside the session: never the ``.rrd`` that ``run`` saved)."""

    session = read_session(session_path)
    rrd = (out or session_path.with_name(f"{session_path.stem}_view.rrd")) if mode == "save" else None
    t0 = min((int(s.host_time_ns[0]) for s in session.streams.values() if len(s)), default=0)
    sink = RerunSink(mode, session_path.stem, rrd, t0_ns=t0, calibration=session_calibration(session.general))
    sink.open([s.spec for s in session.streams.values()])
    for name, s in session.streams.items():
        step = max(1, int(s.spec.rate_hz) or 1000)
        for i in range(0, len(s), step):
            sl = slice(i, i + step)
            sink.write(Batch(name, s.host_time_ns[sl], s.device_time[sl], {k: v[sl] for k, v in s.columns.items()}))
    for t_ns, kind, message in zip(session.events.host_time_ns, session.events.kind, session.events.message):
        sink.event(int(t_ns), str(kind), str(message))
    sink.close()
    return rrd
