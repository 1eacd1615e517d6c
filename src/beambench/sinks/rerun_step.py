"""The step in sight: a text panel with step i of N, the commanded and measured drive frequency, and what the
last finished step did (the contact regime from the plate's normal force, or the walker's speed).

The measured frequency is the motor's mean speed over the last :data:`MEASURED_SPAN_S` of the step in sight: at
a step's start the panel says "settling" until that much of the new step exists (the last step's speed is not
shown beside the new command). The regime is the analysis's own computation on the step's record window
(:data:`StepContacts`, given by the session layer: :func:`beambench.analysis.step_contacts.window_contacts`,
the same times from the window's start, the same frequency), so the panel says what ``steps.csv`` says; without
it, :func:`beambench.acquisition.forces.contact_events.force_regime` at the commanded frequency. The speed is a
straight-line fit of the body's forward position over the record window.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import rerun as rr

from beambench.acquisition.batch import StepRecord
from beambench.acquisition.forces.contact_events import ContactSummary, force_regime
from beambench.acquisition.protocol.plan import step_name
from beambench.sinks.rerun_layout import TIMELINE

MEASURED_SPAN_S = 0.5  # the measured frequency: mean motor velocity over the last half second of the step
MEASURED_EVERY_S = 0.5  # a batch longer than this (a saved file's) updates the panel at this spacing
STANDING_MM_S = 5.0  # a step slower than this walks nowhere (the analysis' speed dead band)
NS = 1_000_000_000

# (mocap times s, markers m by label, force times s, normal force N, motor velocity turn/s, commanded Hz, up axis):
# times from the record window's start
StepContacts = Callable[
    [np.ndarray, dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray, float, "str | None"], ContactSummary
]


class _Series:
    """One stream's samples since the step in sight started (host ns, values)."""

    def __init__(self, shape: tuple[int, ...] = ()) -> None:
        self.t = np.zeros(0, np.int64)
        self.v = np.zeros((0, *shape))

    def add(self, t_ns: np.ndarray, values: np.ndarray) -> None:
        self.t = np.concatenate([self.t, np.asarray(t_ns, np.int64)])
        self.v = np.concatenate([self.v, np.asarray(values, float)])

    def drop_before(self, t_ns: int) -> None:
        keep = int(np.searchsorted(self.t, t_ns, "left"))
        self.t, self.v = self.t[keep:], self.v[keep:]

    def window(self, a_ns: int, b_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """Samples in ``[a, b)``, times in s from ``a`` (as the analysis cuts a record window)."""
        i, j = int(np.searchsorted(self.t, a_ns, "left")), int(np.searchsorted(self.t, b_ns, "left"))
        return (self.t[i:j] - a_ns) / NS, self.v[i:j]


class StepPanel:
    """Follows the steps and writes ``/step`` (a markdown text document) whenever what it says changes."""

    def __init__(
        self,
        rec: rr.RecordingStream,
        total_steps: int | None,
        t0_ns: int,
        contacts: StepContacts | None = None,
        markers: tuple[str, ...] = (),
        up_axis: str | None = None,
    ) -> None:
        self.rec, self.total, self.t0_ns = rec, total_steps, t0_ns
        self.contacts_of, self.markers, self.up_axis = contacts, markers, up_axis
        self.current: StepRecord | None = None
        self.measured_hz: float | None = None
        self.last_done = ""
        self._written_s = -np.inf  # the session time of the last text written
        self._force = _Series()
        self._mocap = _Series((len(markers), 3))
        self._motor = _Series()
        self._body = _Series()

    def step(self, record: StepRecord, t_s: float) -> None:
        """A step started (status running) or ended; ``t_s``: its start or end in session seconds."""
        if record.status == "running":
            self.current = StepRecord(record.index, record.frequency_hz, record.t_start_ns)
            self.measured_hz = None  # settling: the last step's speed is not this step's
            for series in (self._force, self._mocap, self._motor, self._body):
                series.drop_before(record.t_start_ns)
        else:
            self.last_done = self._summary(record)
            self.current = None
            # live, motor samples stamped a little after the step's end may have been shown as the step's already
            t_s = max(t_s, self._written_s)
        self._write(t_s)

    def force(self, t_ns: np.ndarray, normal_n: np.ndarray) -> None:
        self._force.add(t_ns, normal_n)

    def mocap(self, t_ns: np.ndarray, data_m: np.ndarray) -> None:
        """Marker positions (n, markers, 3) in m, NaN where occluded."""
        if len(self.markers):
            self._mocap.add(t_ns, data_m)

    def body(self, t_ns: np.ndarray, forward_mm: np.ndarray) -> None:
        self._body.add(t_ns, forward_mm)

    def motor(self, t_ns: np.ndarray, velocity: np.ndarray) -> None:
        """Motor telemetry (turn/s = drive Hz): the measured frequency, every :data:`MEASURED_EVERY_S` within
        the batch (the mean over the :data:`MEASURED_SPAN_S` before each, of the step in sight only)."""
        self._motor.add(t_ns, velocity)
        if self.current is None:  # between steps the panel is written by the step's end; keep the newest span
            self._motor.drop_before(int(self._motor.t[-1]) - int(10 * MEASURED_SPAN_S * NS))
        span = int(MEASURED_SPAN_S * NS)
        every = int(MEASURED_EVERY_S * NS)
        for tk in range(int(t_ns[-1]), int(t_ns[0]) - 1, -every)[::-1]:
            began = self.current.t_start_ns if self.current is not None else None
            if began is not None and tk - began < span:
                continue  # settling: not yet a span of this step
            i, j = np.searchsorted(self._motor.t, [tk - span, tk], side="right")
            if j > i:
                self.measured_hz = float(np.mean(self._motor.v[i:j]))
                if self.current is not None:
                    self._write((tk - self.t0_ns) / NS)

    def _summary(self, rec: StepRecord) -> str:
        head = f"{step_name(rec.index, self.total)} at {rec.frequency_hz:g} Hz"
        if rec.status != "done":
            return f"{head}: {rec.status}"
        a, b = rec.t_settled_ns, rec.t_end_ns
        tf, normal = self._force.window(a, b)
        if len(tf) > 50 and rec.frequency_hz > 0:
            if self.contacts_of is not None:
                tm, pos = self._mocap.window(a, b)
                markers = {m: pos[:, j] for j, m in enumerate(self.markers)}
                _, velocity = self._motor.window(a, b)
                s = self.contacts_of(tm, markers, tf, normal, velocity, rec.frequency_hz, self.up_axis)
            else:
                s = force_regime(tf, normal, rec.frequency_hz)
            return f"{head}: regime **{s.regime}** ({s.contacts_per_cycle:.2f} contacts/cycle)"
        tb, bx = self._body.window(a, b)
        if len(tb) > 10:
            slope, offset = np.polyfit(tb, bx, 1)
            swing = float(np.ptp(bx - (slope * tb + offset))) / 2
            speed = f"speed **{round(float(slope), 1) or 0.0:+.1f} mm/s**"  # no "-0.0"
            if abs(slope) < STANDING_MM_S:
                return f"{head}: {speed}: no net walking (the body swings ±{swing:.0f} mm in place)"
            return f"{head}: {speed} (the body swings ±{swing:.0f} mm about that)"
        return f"{head}: done"

    def _write(self, t_s: float) -> None:
        lines = []
        c = self.current
        if c is not None:
            lines.append(f"## {step_name(c.index, self.total, 'Step')}: {c.frequency_hz:g} Hz")
        else:
            lines.append("## Between steps")
        commanded = f"commanded {c.frequency_hz:g} Hz · " if c is not None else ""
        if self.measured_hz is not None:
            lines.append(f"**{commanded}measured {self.measured_hz:.2f} Hz** (motor, last {MEASURED_SPAN_S:g} s)")
        elif c is not None:
            lines.append(f"**{commanded}measured: settling** (no {MEASURED_SPAN_S:g} s of this step yet)")
        if self.last_done:
            lines.append(f"Last finished: {self.last_done}")
        self._written_s = max(self._written_s, t_s)
        self.rec.set_time(TIMELINE, duration=t_s)
        self.rec.log("step", rr.TextDocument("\n\n".join(lines), media_type=rr.MediaType.MARKDOWN))
