"""Executes a protocol's steps on a rig: command the motor, settle, record, next — and always idle at the end.

The runner never touches a wire or a file: devices give it batches, the hub hands them to the sinks.
Every exit path (normal end, exception, Ctrl-C, SIGTERM, device fault) commands the motor to idle first,
then drains what the devices still hold, logs the final event and closes the sinks.

Monitors (:mod:`beambench.acquisition.monitors`) may pause a step's record window: while one reports a problem the
window's clock stops (``pause``/``resume`` events mark the gap, the step records longer), and a pause
longer than ``max_pause_s`` ends the run as a fault.
"""

from __future__ import annotations

import math
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from beambench.acquisition.batch import StepRecord
from beambench.acquisition.capabilities import DeviceFault, HasIdleTail, MotorLimits, Rig
from beambench.acquisition.hub import Hub
from beambench.acquisition.monitors import Monitor
from beambench.acquisition.plan import Step


class Terminated(BaseException):
    """Raised in the main thread when SIGTERM arrives (a BaseException, like KeyboardInterrupt)."""


@dataclass
class RunResult:
    status: str  # completed | interrupted | fault | error
    steps_done: int
    message: str = ""


ProgressCallback = Callable[[int, float, float], None]  # (step index, frequency, rig seconds just waited)


@contextmanager
def sigterm_raises() -> Iterator[None]:
    """Turn SIGTERM into :class:`Terminated` while running (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: object) -> None:
        raise Terminated("SIGTERM")

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


class Runner:
    """Runs ``steps`` on ``rig``, streaming every batch to ``hub`` every ``poll_s`` of rig time."""

    def __init__(
        self,
        rig: Rig,
        hub: Hub,
        steps: list[Step],
        limits: MotorLimits,
        poll_s: float = 0.1,
        on_progress: ProgressCallback | None = None,
        monitors: list[Monitor] | None = None,
        max_pause_s: float = 30.0,
    ) -> None:
        self.rig, self.hub, self.steps, self.limits = rig, hub, steps, limits
        self.poll_s = poll_s
        self.on_progress = on_progress
        self.monitors = list(monitors or [])
        self.max_pause_s = max_pause_s
        self._current: StepRecord | None = None
        self.steps_done = 0

    def run(self) -> RunResult:
        result = RunResult("error", 0, "")
        try:
            with sigterm_raises():
                self._check_steps()
                self.hub.event(self.rig.clock.now_ns(), "start", f"{len(self.steps)} steps")
                self.rig.motor.arm(self.limits)
                self.hub.event(self.rig.clock.now_ns(), "armed", "")
                for step in self.steps:
                    self._run_step(step)
                result = RunResult("completed", self.steps_done, "all steps done")
        except KeyboardInterrupt:
            result = RunResult("interrupted", self.steps_done, "interrupted by user (SIGINT)")
        except Terminated:
            result = RunResult("interrupted", self.steps_done, "terminated (SIGTERM)")
        except DeviceFault as exc:
            result = RunResult("fault", self.steps_done, f"device fault: {exc}")
        except Exception as exc:
            result = RunResult("error", self.steps_done, f"{type(exc).__name__}: {exc}")
            raise
        finally:
            self._shutdown(result)
        return result

    # --- steps ----------------------------------------------------------------------------------------
    def _check_steps(self) -> None:
        for s in self.steps:
            if not 0 <= s.frequency_hz <= self.limits.max_frequency_hz:
                raise DeviceFault(f"step {s.index}: {s.frequency_hz} Hz outside 0..{self.limits.max_frequency_hz} Hz")

    def _run_step(self, step: Step) -> None:
        clock = self.rig.clock
        self.rig.motor.set_frequency(step.frequency_hz)
        rec = StepRecord(step.index, step.frequency_hz, clock.now_ns())
        self._current = rec
        self.hub.step(rec)
        self.hub.event(rec.t_start_ns, "step", f"step {step.index}: {step.frequency_hz:g} Hz")
        self._wait(step.settle_s, step)
        rec.t_settled_ns = clock.now_ns()
        self._record(step)
        rec.t_end_ns = clock.now_ns()
        rec.status = "done"
        self.hub.step(rec)
        self._current = None
        self.steps_done += 1

    def _wait(self, seconds: float, step: Step) -> None:
        """Let ``seconds`` of rig time pass in polls of at most ``poll_s``, pumping batches after each."""
        if seconds <= 0:
            return
        n = max(1, math.ceil(seconds / self.poll_s - 1e-9))
        for _ in range(n):
            self._poll(seconds / n)
            if self.on_progress:
                self.on_progress(step.index, step.frequency_hz, seconds / n)

    def _record(self, step: Step) -> None:
        """The record window: ``record_s`` of rig time during which no monitor reports a problem."""
        if not self.monitors:
            self._wait(step.record_s, step)
            return
        clock = self.rig.clock
        self._problem()  # monitors start watching here
        remaining = step.record_s
        paused_at: int | None = None
        while remaining > 1e-9:
            dt = min(self.poll_s, remaining)
            began = clock.now_ns()
            self._poll(dt)
            now = clock.now_ns()
            problem, since = self._problem()
            if problem and paused_at is None:
                paused_at = now
                remaining += max(0, began - since) * 1e-9  # earlier polls that counted bad data (the timeout)
                self.hub.event(now, "pause", f"step {step.index}: {problem}")
            elif problem and (now - paused_at) * 1e-9 > self.max_pause_s:
                raise DeviceFault(f"{problem} (paused longer than monitors.max_pause_s = {self.max_pause_s:g} s)")
            elif not problem and paused_at is not None:
                self.hub.event(now, "resume", f"step {step.index}: after {(now - paused_at) * 1e-9:.2f} s")
                paused_at = None
            elif not problem:
                remaining -= dt  # a poll counts only if it began and ended with good data
                if self.on_progress:
                    self.on_progress(step.index, step.frequency_hz, dt)

    def _poll(self, seconds: float) -> None:
        """Let ``seconds`` of rig time pass, hand the batches to the hub, check the motor."""
        self.rig.clock.wait(seconds)
        self._pump()
        self.rig.motor.check()

    def _problem(self) -> tuple[str | None, int]:
        """(the monitors' reasons joined, or None; the earliest time the data went bad)."""
        now = self.rig.clock.now_ns()
        found = [p for p in (m.problem(now) for m in self.monitors) if p]
        return "; ".join(p.reason for p in found) or None, min((p.since_ns for p in found), default=now)

    def _pump(self) -> None:
        for stream in self.rig.streams:
            self.hub.write(stream.read())
        self.hub.flush()

    # --- shutdown -------------------------------------------------------------------------------------
    def _shutdown(self, result: RunResult) -> None:
        """Idle first, then save: the order matters more than anything else here."""
        # Signals during shutdown must not skip the idle or leave the file open.
        old_int = _ignore(signal.SIGINT)
        old_term = _ignore(signal.SIGTERM)
        try:
            try:
                self.rig.motor.idle()
            except Exception as exc:  # the idle attempt must not hide the original problem
                self.hub.event(self.rig.clock.now_ns(), "error", f"idle failed: {exc}")
            self.hub.event(self.rig.clock.now_ns(), "idle", "motor commanded to idle")
            try:
                # real devices: record a short tail so the session shows the motor stopping
                if isinstance(self.rig, HasIdleTail) and self.rig.idle_tail_s > 0:
                    self.rig.clock.wait(self.rig.idle_tail_s)
                self._pump()
            except Exception as exc:
                self.hub.event(self.rig.clock.now_ns(), "error", f"final read failed: {exc}")
            now = self.rig.clock.now_ns()
            if self._current is not None:
                self._current.t_end_ns = now
                self._current.status = "aborted" if result.status != "fault" else "fault"
                self.hub.step(self._current)
            if result.status == "error":
                result.message = result.message or "error"
            kind = {"completed": "stop"}.get(result.status, result.status)
            self.hub.event(now, kind, result.message)
        finally:
            try:
                self.rig.close()
            finally:
                self.hub.close()
                _restore(signal.SIGINT, old_int)
                _restore(signal.SIGTERM, old_term)


def _ignore(sig: int) -> object:
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(sig, signal.SIG_IGN)


def _restore(sig: int, old: object) -> None:
    if old is not None and threading.current_thread() is threading.main_thread():
        signal.signal(sig, old)  # type: ignore[arg-type]
