"""Live view in Rerun: each batch goes out with ``send_columns`` on a ``session_time`` timeline.

Entities: ``mocap/<marker>`` (Points3D, one point per frame, millimetres), ``mocap/tip_trail`` (LineStrips3D of
the recent tip path, once per batch), ``loadcell/<channel>`` (Scalars, raw counts), ``motor/<column>``
(Scalars), ``events`` (TextLog). A default blueprint shows a 3-D view beside force and motor time series.
"""

from __future__ import annotations

from collections import deque
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from beambench.acquisition.batch import Batch, StreamSpec
from beambench.sinks import RerunMode

TIMELINE = "session_time"
TRAIL_POINTS = 360  # one second of tip path at 360 Hz


_UP = {
    "x": rr.ViewCoordinates.RIGHT_HAND_X_UP,
    "y": rr.ViewCoordinates.RIGHT_HAND_Y_UP,
    "z": rr.ViewCoordinates.RIGHT_HAND_Z_UP,
    "-x": rr.ViewCoordinates.RIGHT_HAND_X_DOWN,
    "-y": rr.ViewCoordinates.RIGHT_HAND_Y_DOWN,
    "-z": rr.ViewCoordinates.RIGHT_HAND_Z_DOWN,
}


def view_coordinates(up_axis: str) -> rr.ViewCoordinates:
    """Rerun's right-handed view coordinates with ``up_axis`` (``y``, ``-z``, ``+x`` …) pointing up."""
    return _UP[up_axis.lstrip("+")]


def blueprint(specs: list[StreamSpec]) -> rrb.Blueprint:
    names = {s.name for s in specs}
    series = []
    if "loadcell" in names:
        series.append(rrb.TimeSeriesView(origin="/loadcell", name="Load cells (counts)"))
    if "motor" in names:
        series.append(rrb.TimeSeriesView(origin="/motor", name="Motor"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/mocap", name="Markers (mm)"),
            rrb.Vertical(*series, rrb.TextLogView(origin="/events", name="Events")),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class RerunSink:
    """A hub sink streaming to the Rerun viewer (spawn/connect) or to an ``.rrd`` file (save)."""

    def __init__(self, mode: RerunMode, recording_id: str, rrd_path: Path | None = None, t0_ns: int = 0) -> None:
        if mode == "off":
            raise ValueError("mode 'off' needs no sink")
        if mode == "save" and rrd_path is None:
            raise ValueError("mode 'save' needs an .rrd path")
        self.mode, self.rrd_path, self.t0_ns = mode, rrd_path, t0_ns
        self.rec = rr.RecordingStream("beambench", recording_id=recording_id)
        self._specs: dict[str, StreamSpec] = {}
        self._trail: deque[np.ndarray] = deque(maxlen=TRAIL_POINTS)

    def open(self, specs: list[StreamSpec]) -> None:
        if self.mode == "save":
            self.rec.save(str(self.rrd_path))
        elif self.mode == "spawn":
            self.rec.spawn()
        else:
            self.rec.connect_grpc()
        self._specs = {s.name: s for s in specs}
        self.rec.send_blueprint(blueprint(specs))
        mocap = self._specs.get("mocap")
        up = mocap.frame.up_axis if mocap is not None and mocap.frame is not None else "z"
        self.rec.log("mocap", view_coordinates(up), static=True)

    def write(self, batch: Batch) -> None:
        spec = self._specs.get(batch.stream)
        if spec is None or len(batch) == 0:
            return
        t = rr.TimeColumn(TIMELINE, duration=(batch.host_time_ns - self.t0_ns) * 1e-9)
        if batch.stream == "mocap":
            self._write_mocap(batch, spec, t)
            return
        for name, col in batch.columns.items():
            cs = spec.columns[name]
            if col.ndim == 1 and np.dtype(cs.dtype).kind != "b" and name not in ("seq", "frame"):
                self.rec.send_columns(f"{batch.stream}/{name}", [t], rr.Scalars.columns(scalars=col.astype(float)))
            elif col.ndim == 2 and cs.labels:
                for j, label in enumerate(cs.labels):
                    self.rec.send_columns(
                        f"{batch.stream}/{label}", [t], rr.Scalars.columns(scalars=col[:, j].astype(float))
                    )

    def _write_mocap(self, batch: Batch, spec: StreamSpec, t: rr.TimeColumn) -> None:
        pos_mm = batch.columns["data"] * 1000.0
        labels = spec.columns["data"].labels
        for j, label in enumerate(labels):
            self.rec.send_columns(f"mocap/{label}", [t], rr.Points3D.columns(positions=pos_mm[:, j, :]))
        if "tip" in labels or "foot" in labels:
            j = labels.index("tip") if "tip" in labels else labels.index("foot")
            self._trail.extend(pos_mm[:, j, :])
            self.rec.set_time(TIMELINE, duration=(int(batch.host_time_ns[-1]) - self.t0_ns) * 1e-9)
            self.rec.log("mocap/tip_trail", rr.LineStrips3D([np.asarray(self._trail)], radii=0.05))

    def event(self, host_time_ns: int, kind: str, message: str) -> None:
        self.rec.set_time(TIMELINE, duration=(host_time_ns - self.t0_ns) * 1e-9)
        level = "ERROR" if kind in ("fault", "error") else "WARN" if kind == "interrupted" else "INFO"
        self.rec.log("events", rr.TextLog(f"{kind}: {message}" if message else kind, level=level))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()
