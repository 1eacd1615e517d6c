"""The step in sight: a text panel with step i of N, the commanded and measured drive frequency, and what the
last finished step did (the contact regime from the plate's normal force, or the walker's speed).

The regime is :func:`beambench.acquisition.forces.contact_events.force_regime` of the step's record window (the rule the
analysis uses); the speed is a straight-line fit of the body's forward position over the record window.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from beambench.acquisition.batch import StepRecord
from beambench.acquisition.forces.contact_events import force_regime
from beambench.sinks.rerun_layout import TIMELINE

MEASURED_SPAN_S = 0.5  # the measured frequency: mean motor velocity over the last half second
MEASURED_EVERY_S = 0.5  # a batch longer than this (a saved file's) updates the panel at this spacing


STANDING_MM_S = 5.0  # a step slower than this walks nowhere (the analysis' speed dead band)


class StepPanel:
    """Follows the steps and writes ``/step`` (a markdown text document) whenever what it says changes."""

    def __init__(self, rec: rr.RecordingStream, total_steps: int | None, t0_ns: int) -> None:
        self.rec, self.total, self.t0_ns = rec, total_steps, t0_ns
        self.current: StepRecord | None = None
        self.measured_hz: float | None = None
        self.last_done = ""
        self._t = np.zeros(0)
        self._normal = np.zeros(0)
        self._bt = np.zeros(0)
        self._bx = np.zeros(0)
        self._mt = np.zeros(0)
        self._mv = np.zeros(0)

    def step(self, record: StepRecord, t_s: float) -> None:
        """A step started (status running) or ended; ``t_s``: its start or end in session seconds."""
        if record.status == "running":
            self.current = StepRecord(record.index, record.frequency_hz, record.t_start_ns)
            self._drop_before(t_s)
        else:
            self.last_done = self._summary(record)
            self.current = None
        self._write(t_s)

    def force(self, t: np.ndarray, normal_n: np.ndarray) -> None:
        self._t, self._normal = np.concatenate([self._t, t]), np.concatenate([self._normal, normal_n])

    def body(self, t: np.ndarray, forward_mm: np.ndarray) -> None:
        self._bt, self._bx = np.concatenate([self._bt, t]), np.concatenate([self._bx, forward_mm])

    def motor(self, t: np.ndarray, velocity: np.ndarray) -> None:
        """Motor telemetry (turn/s = drive Hz): the measured frequency, every :data:`MEASURED_EVERY_S` within
        the batch (the mean over the :data:`MEASURED_SPAN_S` before each)."""
        self._mt = np.concatenate([self._mt, t])[-2000:]
        self._mv = np.concatenate([self._mv, velocity])[-2000:]
        ticks = np.arange(float(t[-1]), float(t[0]), -MEASURED_EVERY_S)[::-1]
        for tk in ticks:
            recent = (self._mt > tk - MEASURED_SPAN_S) & (self._mt <= tk)
            self.measured_hz = float(np.mean(self._mv[recent]))
            if self.current is not None:
                self._write(float(tk))

    def _drop_before(self, t_s: float) -> None:
        keep = self._t >= t_s - 1e-6
        self._t, self._normal = self._t[keep], self._normal[keep]
        keep = self._bt >= t_s - 1e-6
        self._bt, self._bx = self._bt[keep], self._bx[keep]

    def _summary(self, rec: StepRecord) -> str:
        head = f"step {rec.index + 1} ({rec.frequency_hz:g} Hz)"
        if rec.status != "done":
            return f"{head}: {rec.status}"
        a, b = (rec.t_settled_ns - self.t0_ns) * 1e-9, (rec.t_end_ns - self.t0_ns) * 1e-9
        w = (self._t >= a) & (self._t <= b)
        if w.sum() > 50 and rec.frequency_hz > 0:
            s = force_regime(self._t[w], self._normal[w], rec.frequency_hz)
            return f"{head}: regime **{s.regime}** ({s.contacts_per_cycle:.2f} contacts/cycle)"
        w = (self._bt >= a) & (self._bt <= b)
        if w.sum() > 10:
            slope, offset = np.polyfit(self._bt[w], self._bx[w], 1)
            swing = float(np.ptp(self._bx[w] - (slope * self._bt[w] + offset))) / 2
            speed = f"speed **{round(float(slope), 1) or 0.0:+.1f} mm/s**"  # no "-0.0"
            if abs(slope) < STANDING_MM_S:
                return f"{head}: {speed}: no net walking (the body swings ±{swing:.0f} mm in place)"
            return f"{head}: {speed} (the body swings ±{swing:.0f} mm about that)"
        return f"{head}: done"

    def _write(self, t_s: float) -> None:
        lines = []
        c = self.current
        if c is not None:
            of = f" of {self.total}" if self.total else ""
            lines.append(f"## Step {c.index + 1}{of} (index {c.index}): {c.frequency_hz:g} Hz")
        else:
            lines.append("## Between steps")
        if self.measured_hz is not None:
            commanded = f"commanded {c.frequency_hz:g} Hz · " if c is not None else ""
            lines.append(f"**{commanded}measured {self.measured_hz:.2f} Hz** (motor, last {MEASURED_SPAN_S:g} s)")
        if self.last_done:
            lines.append(f"Last finished: {self.last_done}")
        self.rec.set_time(TIMELINE, duration=t_s)
        self.rec.log("step", rr.TextDocument("\n\n".join(lines), media_type=rr.MediaType.MARKDOWN))
