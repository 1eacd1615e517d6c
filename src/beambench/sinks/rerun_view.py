"""Live view in Rerun: batches go out with ``send_columns`` on a ``session_time`` timeline.

Entities: ``mocap/<marker>`` (Points3D, one point per frame, millimetres), ``mocap/tip_trail`` (LineStrips3D of
the recent tip path, once per batch), ``force/normal`` and ``force/tangential`` (Scalars, newtons, through the
load-cell calibration), ``loadcell/<channel>`` (Scalars, raw counts), ``motor/<column>`` (Scalars), ``events``
(TextLog). A default blueprint shows a 3-D view beside force and motor time series.

Chunking: a viewer (spawn/connect) gets every batch as it comes. A saved ``.rrd`` gets each entity's columns
gathered to about :data:`SAVE_CHUNK_BYTES` per ``send_columns`` call, and the row-logged entities (trail,
events) batched by Rerun's chunk batcher to the same size, so a recording comes out near the lower bound of
chunks that ``rerun rrd stats`` computes (its object-store profile targets 2 MiB chunks) and needs no
``rerun rrd optimize``. No entity waits longer than :data:`SAVE_CHUNK_SECONDS` of session time, so a slow
stream (100 Hz motor telemetry needs ~20 min to fill 2 MiB) neither holds memory for an hour-long run nor loses
more than that to a killed one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from beambench.acquisition.batch import Batch, StreamSpec
from beambench.sinks import RerunMode

if TYPE_CHECKING:
    from beambench.acquisition.calibration import LoadCellCalibration

TIMELINE = "session_time"
TRAIL_POINTS = 360  # one second of tip path at 360 Hz
SAVE_CHUNK_BYTES = 2 * 1024 * 1024  # per chunk in a saved .rrd (rerun's object-store chunk target)
SAVE_CHUNK_SECONDS = 60.0  # longest span of session time an entity's columns wait before they are sent
FORCE_LABELS = ("normal", "tangential")


_UP = {
    "x": rr.ViewCoordinates.RIGHT_HAND_X_UP,
    "y": rr.ViewCoordinates.RIGHT_HAND_Y_UP,
    "z": rr.ViewCoordinates.RIGHT_HAND_Z_UP,
    "-x": rr.ViewCoordinates.RIGHT_HAND_X_DOWN,
    "-y": rr.ViewCoordinates.RIGHT_HAND_Y_DOWN,
    "-z": rr.ViewCoordinates.RIGHT_HAND_Z_DOWN,
}


def view_coordinates(up_axis: str) -> rr.components.ViewCoordinates:
    """Rerun's right-handed view coordinates with ``up_axis`` (``y``, ``-z``, ``+x`` …) pointing up."""
    return _UP[up_axis.lstrip("+")]


def blueprint(specs: list[StreamSpec]) -> rrb.Blueprint:
    names = {s.name for s in specs}
    series = []
    if "loadcell" in names:
        series.append(rrb.TimeSeriesView(origin="/force", name="Plate force (N)"))
        series.append(rrb.TimeSeriesView(origin="/loadcell", name="Load cells (raw counts)"))
    if "motor" in names:
        series.append(rrb.TimeSeriesView(origin="/motor", name="Motor"))
    if "track" in names:  # speed tracking: target, measured speed, commanded frequency (acquisition.tracking)
        series.append(rrb.TimeSeriesView(origin="/track", name="Speed tracking"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/mocap", name="Markers (mm)"),
            rrb.Vertical(*series, rrb.TextLogView(origin="/events", name="Events")),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


@dataclass
class _Pending:
    """Columns of one entity waiting to go out in one ``send_columns`` call."""

    kind: str  # "scalars" or "points"
    times: list[np.ndarray] = field(default_factory=list)
    values: list[np.ndarray] = field(default_factory=list)
    nbytes: int = 0


class RerunSink:
    """A hub sink streaming to the Rerun viewer (spawn/connect) or to an ``.rrd`` file (save).

    ``calibration`` turns the load cells' raw counts into plate forces (N) shown beside them; without it only
    the counts are shown."""

    def __init__(
        self,
        mode: RerunMode,
        recording_id: str,
        rrd_path: Path | None = None,
        t0_ns: int = 0,
        calibration: LoadCellCalibration | None = None,
    ) -> None:
        if mode == "off":
            raise ValueError("mode 'off' needs no sink")
        if mode == "save" and rrd_path is None:
            raise ValueError("mode 'save' needs an .rrd path")
        self.mode, self.rrd_path, self.t0_ns, self.calibration = mode, rrd_path, t0_ns, calibration
        # A file is read after the run: gather big chunks. A viewer wants every batch now.
        self.chunk_bytes = SAVE_CHUNK_BYTES if mode == "save" else 0
        self.chunk_seconds = SAVE_CHUNK_SECONDS if mode == "save" else 0.0
        batcher = (
            rr.ChunkBatcherConfig(flush_tick=timedelta(seconds=SAVE_CHUNK_SECONDS), flush_num_bytes=SAVE_CHUNK_BYTES)
            if mode == "save"
            else None
        )
        self.rec = rr.RecordingStream("beambench", recording_id=recording_id, batcher_config=batcher)
        self._specs: dict[str, StreamSpec] = {}
        self._trail = np.zeros((0, 3), np.float32)  # the tip's last TRAIL_POINTS positions (mm)
        self._trail_new = 0  # positions added since the trail was last logged
        # A viewer redraws the trail every batch; a saved file needs it once per TRAIL_POINTS positions (each
        # logged trail is then a new second of path, not ten overlapping copies of it).
        self._trail_every = TRAIL_POINTS if mode == "save" else 1
        self._pending: dict[str, _Pending] = {}

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
        t = (batch.host_time_ns - self.t0_ns) * 1e-9
        if batch.stream == "mocap":
            self._write_mocap(batch, spec, t)
            return
        for name, col in batch.columns.items():
            cs = spec.columns[name]
            if col.ndim == 1 and np.dtype(cs.dtype).kind != "b" and name not in ("seq", "frame"):
                self._send(f"{batch.stream}/{name}", "scalars", t, col.astype(float))
            elif col.ndim == 2 and cs.labels:
                for j, label in enumerate(cs.labels):
                    self._send(f"{batch.stream}/{label}", "scalars", t, col[:, j].astype(float))
        if batch.stream == "loadcell" and self.calibration is not None and "data" in batch.columns:
            force = self.calibration.force_from_counts(batch.columns["data"])
            for j, label in enumerate(FORCE_LABELS):
                self._send(f"force/{label}", "scalars", t, force[:, j])

    def _write_mocap(self, batch: Batch, spec: StreamSpec, t: np.ndarray) -> None:
        pos_mm = batch.columns["data"] * 1000.0
        labels = spec.columns["data"].labels
        for j, label in enumerate(labels):
            self._send(f"mocap/{label}", "points", t, pos_mm[:, j, :].astype(np.float32))
        if "tip" in labels or "foot" in labels:
            j = labels.index("tip") if "tip" in labels else labels.index("foot")
            self._trail = np.concatenate([self._trail, pos_mm[:, j, :].astype(np.float32)])[-TRAIL_POINTS:]
            self._trail_new += len(t)
            if self._trail_new >= self._trail_every:
                self._trail_new = 0
                self.rec.set_time(TIMELINE, duration=float(t[-1]))
                self.rec.log("mocap/tip_trail", rr.LineStrips3D([self._trail], radii=0.05))

    def _send(self, entity: str, kind: str, t: np.ndarray, values: np.ndarray) -> None:
        """Queue one entity's columns; send them once about :attr:`chunk_bytes` are waiting."""
        p = self._pending.setdefault(entity, _Pending(kind))
        p.times.append(np.asarray(t, float))
        p.values.append(values)
        p.nbytes += values.nbytes + 8 * len(t)
        if p.nbytes >= self.chunk_bytes or float(t[-1]) - float(p.times[0][0]) >= self.chunk_seconds:
            self._flush(entity)

    def _flush(self, entity: str) -> None:
        p = self._pending.pop(entity, None)
        if p is None or not p.times:
            return
        times = rr.TimeColumn(TIMELINE, duration=np.concatenate(p.times))
        values = np.concatenate(p.values)
        if p.kind == "points":
            self.rec.send_columns(entity, [times], rr.Points3D.columns(positions=values))
        else:
            self.rec.send_columns(entity, [times], rr.Scalars.columns(scalars=values))

    def event(self, host_time_ns: int, kind: str, message: str) -> None:
        self.rec.set_time(TIMELINE, duration=(host_time_ns - self.t0_ns) * 1e-9)
        level = "ERROR" if kind in ("fault", "error") else "WARN" if kind == "interrupted" else "INFO"
        self.rec.log("events", rr.TextLog(f"{kind}: {message}" if message else kind, level=level))

    def close(self) -> None:
        for entity in list(self._pending):
            self._flush(entity)
        self.rec.flush()
        self.rec.disconnect()
