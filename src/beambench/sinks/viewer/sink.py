"""Live view in Rerun: batches go out with ``send_columns`` on a ``session_time`` timeline.

Entities (millimetres in the mocap stream's frame): ``mocap/<marker>`` (labelled Points3D, one per frame),
``mocap/beam/<end>`` (LineStrips3D through the markers, one per frame), ``mocap/trail/<foot>`` (a short fading
trail), ``mocap/plate`` (Boxes3D, plate rigs), ``mocap/body_trail``, ``mocap/floor``, ``mocap/floor_lines`` and
``mocap/follow`` (walker: the Transform3D of the frame its 3-D view follows the body in); ``body/forward``
and ``body/speed`` (walker, mm and mm/s); ``force/normal`` and ``force/tangential`` (Scalars, newtons, through
the load-cell calibration), ``loadcell/<channel>`` (raw counts), ``motor/velocity``, ``motor/velocity_setpoint``
and ``motor/iq_measured``; ``step`` (TextDocument: step i of N, commanded and measured frequency, the last
step's regime or speed) and ``events`` (TextLog). Counters, states and the motor position stay in the HDF5
session. The blueprint is made per rig from the streams' specs (:mod:`beambench.sinks.viewer.layout`) and sent
with the first mocap frame, which frames the camera.

Chunking: a viewer (spawn/connect) gets every batch as it comes. A saved ``.rrd`` gets each entity's columns
gathered to about :data:`SAVE_CHUNK_BYTES` per ``send_columns`` call, and the row-logged entities (trails,
step, events) batched by Rerun's chunk batcher to the same size, so a recording comes out near the lower bound
of chunks that ``rerun rrd stats`` computes (its object-store profile targets 2 MiB chunks) and needs no
``rerun rrd optimize``. No entity waits longer than :data:`SAVE_CHUNK_SECONDS` of session time, so a slow
stream (100 Hz motor telemetry needs ~20 min to fill 2 MiB) neither holds memory for an hour-long run nor loses
more than that to a killed one.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from beambench.acquisition.batch import Batch, StepRecord, StreamSpec
from beambench.common.unfinished import leave_unfinished
from beambench.sinks.viewer import RerunMode
from beambench.sinks.viewer.layout import TIMELINE, RigLayout, blueprint, layout_of, series_styles
from beambench.sinks.viewer.scene import FOLLOW_ENTITY, Scene3D
from beambench.sinks.viewer.spawn import spawn_viewer, viewer_url
from beambench.sinks.viewer.step import StepContacts, StepPanel

if TYPE_CHECKING:
    from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration

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


class RecordingNotFinished(RuntimeError):
    """A recording's close failed or was given up (its file could not be written: a full disk?); ``label`` names
    the recording (``recording PATH`` or ``live view``), the message says why."""

    def __init__(self, label: str, reason: str) -> None:
        super().__init__(reason)
        self.label = label


@dataclass
class _Pending:
    """Columns of one entity waiting to go out in one ``send_columns`` call."""

    kind: str  # "scalars", "points", "translations", "strips" (a line strip per row) or "segments" (several per row)
    times: list[np.ndarray] = field(default_factory=list)
    values: list[np.ndarray] = field(default_factory=list)
    nbytes: int = 0


class RerunSink:
    """A hub sink streaming to the Rerun viewer (spawn/connect) or to an ``.rrd`` file (save).

    ``calibration`` turns the load cells' raw counts into plate forces (N) shown beside them; without it only
    the counts are shown. ``rig`` (the session's rig name) and ``total_steps`` shape the layout and the step
    panel; the layout itself comes from the streams' specs. ``step_contacts``: the analysis's computation of a
    step's contacts (:data:`beambench.sinks.viewer.step.StepContacts`), so the step panel says what the report
    says."""

    def __init__(
        self,
        mode: RerunMode,
        recording_id: str,
        rrd_path: Path | None = None,
        t0_ns: int = 0,
        calibration: LoadCellCalibration | None = None,
        rig: str | None = None,
        total_steps: int | None = None,
        step_contacts: StepContacts | None = None,
    ) -> None:
        if mode == "off":
            raise ValueError("mode 'off' needs no sink")
        if mode == "save" and rrd_path is None:
            raise ValueError("mode 'save' needs an .rrd path")
        self.mode, self.rrd_path, self.t0_ns, self.calibration = mode, rrd_path, t0_ns, calibration
        self.label = f"recording {rrd_path}" if mode == "save" else "live view"
        self.rig, self.total_steps = rig, total_steps
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
        self._pending: dict[str, _Pending] = {}
        self.layout: RigLayout = layout_of([], rig)
        self._scene: Scene3D | None = None
        self._step_contacts = step_contacts
        self._steps = StepPanel(self.rec, total_steps, t0_ns)
        self._blueprint_sent = False
        self._framed: tuple[np.ndarray, np.ndarray] | None = None  # the box the 3-D eye was framed on
        self._next_frame = -np.inf

    def open(self, specs: list[StreamSpec]) -> None:
        if self.mode == "save":
            self.rec.save(str(self.rrd_path))
        elif self.mode == "spawn":  # on loopback only (rr.spawn's viewer listens on every interface)
            spawn_viewer()
            self.rec.connect_grpc(viewer_url())
        else:
            self.rec.connect_grpc()
        self._specs = {s.name: s for s in specs}
        self.layout = layout_of(specs, self.rig)
        self._steps = StepPanel(
            self.rec, self.total_steps, self.t0_ns, self._step_contacts, self.layout.markers, self.layout.up_axis
        )
        self.rec.log("mocap", view_coordinates(self.layout.up_axis), static=True)
        if self.layout.body is not None:  # the walker's view frame: its up is the stream's
            self.rec.log(FOLLOW_ENTITY, view_coordinates(self.layout.up_axis), static=True)
        for entity, style in series_styles(self.layout).items():
            self.rec.log(entity, style, static=True)
        if self.layout.markers:
            self._scene = Scene3D(self.rec, self.layout, self._send, live=self.mode != "save")
            self._scene.log_static()
        else:  # nothing to frame the camera on: the layout now
            self._send_blueprint(None)

    def _send_blueprint(self, box: tuple[np.ndarray, np.ndarray] | None) -> None:
        """The layout, its 3-D eye framed on ``box`` (the scene's extent, mm; None: the viewer's own)."""
        camera = self._scene.camera(*box) if self._scene is not None and box is not None else None
        self.rec.send_blueprint(blueprint(self.layout, camera, live=self.mode != "save"))
        self._blueprint_sent = True
        self._framed = box

    def write(self, batch: Batch) -> None:
        spec = self._specs.get(batch.stream)
        if spec is None or len(batch) == 0:
            return
        t = (batch.host_time_ns - self.t0_ns) * 1e-9
        if batch.stream == "mocap":
            self._write_mocap(batch, t)
            return
        for name, col in batch.columns.items():
            if not self.layout.logged(batch.stream, name):
                continue
            cs = spec.columns[name]
            if col.ndim == 1:
                self._send(f"{batch.stream}/{name}", "scalars", t, col.astype(float))
            elif col.ndim == 2 and cs.labels:
                for j, label in enumerate(cs.labels):
                    self._send(f"{batch.stream}/{label}", "scalars", t, col[:, j].astype(float))
        if batch.stream == "motor" and "velocity" in batch.columns:
            self._steps.motor(batch.host_time_ns, batch.columns["velocity"])
        if batch.stream == "loadcell" and self.calibration is not None and "data" in batch.columns:
            force = self.calibration.force_from_counts(batch.columns["data"])
            if self.layout.plate:
                for j, label in enumerate(FORCE_LABELS):
                    self._send(f"force/{label}", "scalars", t, force[:, j])
                self._steps.force(batch.host_time_ns, force[:, 0])
                if self._scene is not None:
                    self._scene.contacts(t, force[:, 0])

    def _write_mocap(self, batch: Batch, t: np.ndarray) -> None:
        if self.layout.plate and self._step_contacts is not None:  # the stage's frequency for the step's contacts
            data = np.asarray(batch.columns["data"], float)
            occluded = batch.columns.get("occluded")
            if occluded is not None and len(occluded) == len(data):  # as the analysis reads it: NaN where not seen
                data = np.where(np.asarray(occluded, bool)[..., None], np.nan, data)
            self._steps.mocap(batch.host_time_ns, data)
        pos_mm = (batch.columns["data"] * 1000.0).astype(np.float32)
        if self._scene is not None:
            self._scene.write(t, pos_mm)
            box = self._scene.extent()
            # framed on the first frames, and anew (at most every REFRAME_EVERY_S) when the scene outgrows that:
            # a saved file's last framing holds the whole session
            due = self._framed is None or (t[-1] >= self._next_frame and self._scene.outgrown(self._framed))
            if box is not None and due:
                self._send_blueprint(box)
                self._next_frame = float(t[-1]) + REFRAME_EVERY_S
        elif not self._blueprint_sent:
            self._send_blueprint(None)
        body = self.layout.body
        if body is not None:
            j = self.layout.markers.index(body)
            self._steps.body(batch.host_time_ns, pos_mm[:, j, :] @ self.layout.forward_vector())

    def step(self, record: StepRecord) -> None:
        """A protocol step started or ended: the step panel (and, at its end, the step's regime or speed)."""
        t_ns = record.t_start_ns if record.status == "running" else record.t_end_ns
        self._steps.step(record, (t_ns - self.t0_ns) * 1e-9)

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
        elif p.kind in ("strips", "segments"):  # (rows, points, 3): a strip a row; (rows, k, points, 3): k a row
            per_row = 1 if p.kind == "strips" else values.shape[1]
            flat = values.reshape(-1, values.shape[-2], 3)  # equal-length strips: Rerun's numpy path
            strips = rr.LineStrips3D.columns(strips=flat).partition(np.full(len(values), per_row, np.int32))
            self.rec.send_columns(entity, [times], strips)
        elif p.kind == "translations":
            self.rec.send_columns(entity, [times], rr.Transform3D.columns(translation=values))
        else:
            self.rec.send_columns(entity, [times], rr.Scalars.columns(scalars=values))

    def event(self, host_time_ns: int, kind: str, message: str) -> None:
        self.rec.set_time(TIMELINE, duration=(host_time_ns - self.t0_ns) * 1e-9)
        level = "ERROR" if kind in ("fault", "error") else "WARN" if kind == "interrupted" else "INFO"
        text = message if message.startswith(kind) else f"{kind}: {message}" if message else kind
        self.rec.log("events", rr.TextLog(text, level=level))

    def close(self) -> None:
        """Send what waits, flush and disconnect, within :data:`CLOSE_TIMEOUT_S`: on a full disk the SDK's file
        sink may never finish (``RecordingStream::set_sink`` waits for it), so the wait is bounded and given up.

        A recording that did not finish (given up, or its file sink stopped at a write error) is left unfinished
        (:mod:`beambench.common.unfinished`), its stream kept: dropping it (the garbage collector, the SDK's exit
        hook) waits for the stuck sink for ever, so the command line ends the process past them."""
        try:
            for entity in list(self._pending):
                self._flush(entity)
        finally:
            try:
                finished = _within(self._finish, CLOSE_TIMEOUT_S)
                why = f"not finished within {CLOSE_TIMEOUT_S:g} s (a full disk?): it may be cut short"
            except RuntimeError as exc:  # the SDK's file sink stopped at a write error ("File-writer thread …")
                finished, why = False, f"not finished ({exc}; a full disk?): it may be cut short"
            if not finished:
                rr.unregister_shutdown()  # for a caller that ends the process itself: one hook less that would wait
                leave_unfinished(self.label, self.rec)
                raise RecordingNotFinished(self.label, why)

    def _finish(self) -> None:
        self.rec.flush(timeout_sec=CLOSE_TIMEOUT_S)
        self.rec.disconnect()


REFRAME_EVERY_S = 5.0  # the 3-D eye is framed anew at most this often (session seconds)
CLOSE_TIMEOUT_S = 5.0  # the longest a recording's close may take before it is given up


def _within(fn: Callable[[], None], timeout_s: float) -> bool:
    """Run ``fn`` in a daemon thread; True if it returned within ``timeout_s`` (its exception is re-raised)."""
    errors: list[BaseException] = []

    def target() -> None:
        try:
            fn()
        except BaseException as exc:
            errors.append(exc)

    t = threading.Thread(target=target, name="rerun-close", daemon=True)
    t.start()
    t.join(timeout_s)
    if t.is_alive():
        return False
    if errors:
        raise errors[0]
    return True
