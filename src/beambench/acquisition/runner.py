"""Executes a protocol's steps on a rig: command the motor, settle, record, next — and always idle at the end.

The runner never touches a wire or a file: devices give it batches, the hub hands them to the sinks.
Every exit path (normal end, exception, Ctrl-C, SIGTERM, device fault) commands the motor to idle first,
then drains what the devices still hold, logs the final event and closes the sinks.

Stop signals (:mod:`beambench.acquisition.stop_signals`) never raise: they only set a :class:`StopSignal` flag,
which the runner reads before and after every poll (settle, record, pause) and between steps.

What a step commands is its :class:`~beambench.acquisition.step_control.StepControl`'s: a sweep's fixed frequency
(the default), or the speed controller's choice after every poll (speed tracking).

Monitors (:mod:`beambench.acquisition.monitors`) may pause a step's record window: while one reports a problem the
window's clock stops (``pause``/``resume`` events mark the gap, the step records longer), and a pause
longer than ``max_pause_s`` ends the run as a fault.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from beambench.acquisition.batch import StepRecord
from beambench.acquisition.capabilities import (
    Anticipates,
    ChecksDevices,
    ConfirmsIdle,
    DeviceFault,
    HasIdleTail,
    MotorLimits,
    ReportsDeviceHealth,
    ReportsSinkFailure,
    Rig,
)
from beambench.acquisition.hub import Hub, SinkFailure
from beambench.acquisition.monitors import Monitor
from beambench.acquisition.protocol.plan import Step, step_name
from beambench.acquisition.step_control import FixedFrequency, StepControl
from beambench.acquisition.stop_signals import StopSignal, stop_on_signals
from beambench.common.out_of_memory import out_of_memory_here
from beambench.common.unfinished import leave_unfinished


class Terminated(BaseException):
    """Kept for callers that raise it themselves: treated like a SIGTERM (the run ends as interrupted)."""


class _DeviceSinkFailed(Exception):
    """A device's own file (the CAN log) failed: the run stops as a sink failure (exit 4), motor idle first."""


class _Stopped(BaseException):
    """Raised by the runner itself (never by a signal handler) when a stop was requested."""


@dataclass
class RunResult:
    status: str  # completed | interrupted | fault | failed (a critical sink: the session file) | error
    steps_done: int
    message: str = ""
    warnings: list[str] = field(default_factory=list)  # what went wrong besides (a live view or recording lost)
    idle: str = "motor idled"  # what the motor's state is known to be at the end (confirmed by the device or not)


ProgressCallback = Callable[[int, float, float], None]  # (step index, frequency, rig seconds just waited)


def wait_polls(seconds: float, poll_s: float) -> list[float]:
    """The polls that let ``seconds`` of rig time pass: equal ones of at most ``poll_s`` (settle windows)."""
    if seconds <= 0:
        return []
    n = max(1, math.ceil(seconds / poll_s - 1e-9))
    return [seconds / n] * n


def record_polls(seconds: float, poll_s: float) -> list[float]:
    """The polls of a monitored record window that no monitor pauses: ``poll_s`` each, the remainder last."""
    polls, remaining = [], seconds
    while remaining > 1e-9:
        dt = min(poll_s, remaining)
        polls.append(dt)
        remaining -= dt
    return polls


def _ran_out_of_memory() -> None:
    """The process ran out of memory: a library that failed to allocate may have left its heap damaged (seen:
    glibc's "corrupted double-linked list" at the interpreter's exit), so the command line ends the process past
    the exit handlers (:mod:`beambench.common.unfinished`). Plain try: recording it allocates too."""
    try:  # noqa: SIM105
        leave_unfinished("memory: the process ran out of it")
    except BaseException:
        pass


class Runner:
    """Runs ``steps`` on ``rig``, streaming every batch to ``hub`` every ``poll_s`` of rig time; ``control`` chooses
    each step's frequency (default: the step's own)."""

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
        stop: StopSignal | None = None,
        control: StepControl | None = None,
    ) -> None:
        self.rig, self.hub, self.steps, self.limits = rig, hub, steps, limits
        self.control: StepControl = control or FixedFrequency()
        self._commanded: float | None = None
        self.poll_s = poll_s
        self.on_progress = on_progress
        self.monitors = list(monitors or [])
        self.max_pause_s = max_pause_s
        self.stop = stop or StopSignal()
        self._current: StepRecord | None = None
        self.steps_done = 0

    def run(self) -> RunResult:
        # The handlers stay installed through the shutdown: a signal there only sets the (already set) flag.
        with stop_on_signals(self.stop):
            result = RunResult("error", 0, "")
            try:
                self._check_stop()
                self.control.check(self.steps, self.limits)
                self.hub.event(self.rig.clock.now_ns(), "start", f"{len(self.steps)} steps")
                self._check_stop()
                self.rig.motor.arm(self.limits)
                self.hub.event(self.rig.clock.now_ns(), "armed", "")
                if isinstance(self.rig, Anticipates):
                    self.rig.anticipate(self.schedule())
                for step in self.steps:
                    self._check_stop()
                    self._run_step(step)
                result = RunResult("completed", self.steps_done, "all steps done")
            except _Stopped:
                result = RunResult("interrupted", self.steps_done, self.stop.reason)
            except (SinkFailure, _DeviceSinkFailed) as exc:
                result = RunResult("failed", self.steps_done, str(exc))
            except KeyboardInterrupt:  # raised by code outside our handlers (e.g. a caller's thread)
                result = RunResult("interrupted", self.steps_done, "interrupted by user (SIGINT)")
            except Terminated:
                result = RunResult("interrupted", self.steps_done, "terminated (SIGTERM)")
            except DeviceFault as exc:
                if self.stop.requested:  # a fault raised while stopping (e.g. a device closed under us)
                    result = RunResult("interrupted", self.steps_done, f"{self.stop.reason}; then {exc}")
                else:
                    result = RunResult("fault", self.steps_done, f"device fault: {exc}{self._during_flood()}")
            except MemoryError:  # the shutdown below idles the motor without allocating; then one line
                result = RunResult("error", self.steps_done, "out of memory (MemoryError)")
                _ran_out_of_memory()
            except (RuntimeError, SystemError) as exc:  # MuJoCo's, a thread refused, an extension's unset error
                reason = out_of_memory_here(exc)
                if reason is None:
                    result = RunResult("error", self.steps_done, f"{type(exc).__name__}: {exc}")
                    raise
                result = RunResult("error", self.steps_done, f"out of memory ({reason})")
                _ran_out_of_memory()
            except Exception as exc:
                result = RunResult("error", self.steps_done, f"{type(exc).__name__}: {exc}")
                raise
            finally:
                self._shutdown(result)
                failure = self.hub.failure or self._device_sink_failure()
                if failure is not None and result.status != "failed":  # a file failed while closing
                    before = f"; the run had {result.status}: {result.message}" if result.status != "completed" else ""
                    result.status, result.message = "failed", f"{failure}{before}"
            return result

    def _say_lost(self, now_ns: int, health: dict[str, dict[str, Any]], result: RunResult) -> None:
        """Frames a stream's device sent that never arrived: a ``lost`` event and a warning (said on stderr)."""
        for stream, counts in sorted(health.items()):
            lost, got = counts.get("dropped", 0), counts.get("received", 0)
            if isinstance(lost, int) and isinstance(got, int) and lost > 0:
                text = f"{stream}: {lost} frames lost of {lost + got} ({100 * lost / (lost + got):.1f} %)"
                self._log_event(now_ns, "lost", text)
                result.warnings.append(text)

    def _say_flood(self, now_ns: int, health: dict[str, dict[str, Any]], result: RunResult) -> None:
        """A link flooded with datagrams not from its device: a ``flood`` event naming the sender and how many were
        dropped, and a warning (said on stderr), once per link at the end of the run."""
        for stream, counts in sorted(health.items()):
            flood = counts.get("flood")
            if isinstance(flood, str) and flood:
                text = f"{stream}: {flood}"
                self._log_event(now_ns, "flood", text)
                if "during a flood" not in result.message:  # a fault's line names it already
                    result.warnings.append(text)

    def _during_flood(self) -> str:
        """``; during a flood: …`` when a link was flooded (a fault then follows from the frames the flood pushed
        out of the buffers, not from the device), else ""."""
        if not isinstance(self.rig, ReportsDeviceHealth):
            return ""
        try:
            health = self.rig.device_health()
        except Exception:
            return ""
        floods = [
            f"{stream}: {c['flood'].removeprefix('flood: ')}" for stream, c in sorted(health.items()) if c.get("flood")
        ]
        return f" (during a flood: {'; '.join(floods)})" if floods else ""

    def _log_event(self, now_ns: int, kind: str, message: str) -> None:
        """An event during the shutdown: a sink failing now is in ``hub.failure``, never raised."""
        with contextlib.suppress(SinkFailure, MemoryError):
            self.hub.event(now_ns, kind, message)

    def _check_stop(self) -> None:
        if self.stop.requested:
            raise _Stopped(self.stop.reason)

    # --- steps ----------------------------------------------------------------------------------------
    def schedule(self) -> list[tuple[float, list[float]]]:
        """What the run will do if nothing stops or pauses it: each step's frequency and the rig-clock waits (polls)
        that follow its command, in order (a hint for rigs that compute ahead, :class:`Anticipates`); none when
        the frequencies depend on the data (a closed-loop :class:`StepControl`)."""
        if self.control.closed_loop:
            return []
        record = record_polls if self.monitors else wait_polls
        return [
            (s.frequency_hz, wait_polls(s.settle_s, self.poll_s) + record(s.record_s, self.poll_s)) for s in self.steps
        ]

    def _run_step(self, step: Step) -> None:
        clock = self.rig.clock
        start = self.control.start(step, clock.now_ns())
        if start.command_hz is not None:  # every step's start is commanded, a repeat of the last frequency too
            self.rig.motor.set_frequency(start.command_hz)
            self._commanded = start.command_hz
        rec = StepRecord(
            step.index, start.frequency_hz, clock.now_ns(), direction=step.direction, kind=step.kind, repeat=step.repeat
        )
        self._begin_step(rec, start.message)
        self._wait(step.settle_s, step)
        rec.t_settled_ns = clock.now_ns()
        self._record(step)
        self._end_step(rec)

    def _command(self, frequency_hz: float) -> None:
        """Command ``frequency_hz`` unless the motor was last told it."""
        if frequency_hz != self._commanded:
            self.rig.motor.set_frequency(frequency_hz)
            self._commanded = frequency_hz

    def _steer(self, step: Step) -> float:
        """After a poll of ``step``: its control's frequency, commanded if it changed."""
        frequency = self.control.tick(step, self.rig.clock.now_ns())
        self._command(frequency)
        return frequency

    def _begin_step(self, rec: StepRecord, message: str) -> None:
        """A step starts: it is the one an abort closes, the sinks get its row and a ``step`` event. The event goes
        out even when a critical sink failed on the row (a full disk): that sink still takes closing records, and
        the step it will close has its event beside its row."""
        self._current = rec
        try:
            self.hub.step(rec)
        finally:
            self.hub.event(rec.t_start_ns, "step", message)

    def _end_step(self, rec: StepRecord) -> None:
        """A step ran to its end: its row is closed ``done``. It is no longer the one an abort closes before the
        sinks get that row: a critical sink failing on it (a full disk) stops the run, but the step stays done."""
        rec.t_end_ns = self.rig.clock.now_ns()
        rec.status = "done"
        self._current = None
        self.steps_done += 1
        self.hub.step(rec)

    def _wait(self, seconds: float, step: Step) -> None:
        """Let ``seconds`` of rig time pass in polls of at most ``poll_s``, pumping batches after each."""
        for dt in wait_polls(seconds, self.poll_s):
            self._check_stop()
            self._poll(dt)
            frequency = self._steer(step)
            if self.on_progress:
                self.on_progress(step.index, frequency, dt)

    def _record(self, step: Step) -> None:
        """The record window: ``record_s`` of rig time during which no monitor reports a problem."""
        if not self.monitors:
            self._wait(step.record_s, step)
            return
        clock = self.rig.clock
        self._problem()  # monitors start watching here
        remaining = step.record_s
        paused_at: int | None = None
        while remaining > 1e-9:  # as record_polls() while nothing pauses
            self._check_stop()
            dt = min(self.poll_s, remaining)
            began = clock.now_ns()
            self._poll(dt)
            frequency = self._steer(step)
            now = clock.now_ns()
            problem, since = self._problem()
            if problem and paused_at is None:
                paused_at = now
                remaining += max(0, began - since) * 1e-9  # earlier polls that counted bad data (the timeout)
                self.hub.event(now, "pause", f"{step_name(step.index, len(self.steps))}: {problem}")
            elif problem and paused_at is not None and (now - paused_at) * 1e-9 > self.max_pause_s:
                raise DeviceFault(f"{problem} (paused longer than monitors.max_pause_s = {self.max_pause_s:g} s)")
            elif not problem and paused_at is not None:
                self.hub.event(
                    now, "resume", f"{step_name(step.index, len(self.steps))}: after {(now - paused_at) * 1e-9:.2f} s"
                )
                paused_at = None
            elif not problem:
                remaining -= dt  # a poll counts only if it began and ended with good data
                if self.on_progress:
                    self.on_progress(step.index, frequency, dt)

    def _poll(self, seconds: float) -> None:
        """Let ``seconds`` of rig time pass, hand the batches to the hub, check the motor."""
        self._check_stop()
        self.rig.clock.wait(seconds)
        self._pump()
        self._check_stop()  # before check(): a device closed by a stopping peer must not read as a fault
        if isinstance(self.rig, ChecksDevices):
            self.rig.check()  # the motor, then every stream's liveness
        else:
            self.rig.motor.check()
        failed = self._device_sink_failure()
        if failed is not None:
            raise _DeviceSinkFailed(failed)

    def _device_sink_failure(self) -> str | None:
        motor = self.rig.motor
        return motor.sink_failure() if isinstance(motor, ReportsSinkFailure) else None

    def _problem(self) -> tuple[str | None, int]:
        """(the monitors' reasons joined, or None; the earliest time the data went bad)."""
        now = self.rig.clock.now_ns()
        found = [p for p in (m.problem(now) for m in self.monitors) if p]
        return "; ".join(p.reason for p in found) or None, min((p.since_ns for p in found), default=now)

    def _pump(self) -> None:
        for stream in self.rig.streams:
            self.hub.write(stream.read())
        self.hub.flush()

    def _drain(self) -> None:
        """The final read: every stream's rows to the hub, each stream on its own (one whose device failed, or
        stopped with the run, must not keep the others' rows out of the session)."""
        for stream in self.rig.streams:
            try:
                batch = stream.read()
            except Exception as exc:  # SinkFailure is not raised by a read
                self._log_event(self.rig.clock.now_ns(), "error", f"final read of {stream.name} failed: {exc}")
                continue
            self.hub.write(batch)
        self.hub.flush()

    # --- shutdown -------------------------------------------------------------------------------------
    def _shutdown(self, result: RunResult) -> None:
        """Idle first, then save: the order matters more than anything else here. Nothing here raises before
        the rig and the sinks are closed: a sink that fails now is only recorded (``hub.failure``)."""
        # Signals during shutdown only set the stop flag (see run()): they cannot skip the idle.
        try:
            said = "motor commanded to idle"
            try:
                self.rig.motor.idle()
                if isinstance(self.rig.motor, ConfirmsIdle):
                    said = result.idle = self.rig.motor.confirm_idle()
            except MemoryError:  # the idle frames went out (they need no memory); its confirmation could not
                said = result.idle = "motor commanded to idle (out of memory: not confirmed)"
            except Exception as exc:  # the idle attempt must not hide the original problem
                self._log_event(self.rig.clock.now_ns(), "error", f"idle failed: {exc}")
            self._log_event(self.rig.clock.now_ns(), "idle", said)
            try:
                # real devices: record a short tail so the session shows the motor stopping
                if isinstance(self.rig, HasIdleTail) and self.rig.idle_tail_s > 0:
                    self.rig.clock.wait(self.rig.idle_tail_s)
                self._drain()
            except SinkFailure:
                pass  # recorded in hub.failure
            except Exception as exc:
                self._log_event(self.rig.clock.now_ns(), "error", f"final read failed: {exc}")
            now = self.rig.clock.now_ns()
            if self._current is not None:
                self._current.t_end_ns = now
                self._current.status = {"fault": "fault", "failed": "failed"}.get(result.status, "aborted")
                with contextlib.suppress(SinkFailure):
                    self.hub.step(self._current)
            if result.status == "error":
                result.message = result.message or "error"
            if isinstance(self.rig, ReportsDeviceHealth):
                try:
                    health = self.rig.device_health()
                except Exception as exc:
                    health = {"error": {"message": str(exc)}}
                for stream, counts in sorted(health.items()):
                    listed = ", ".join(f"{k} {v}" for k, v in sorted(counts.items()) if k != "flood")  # its own event
                    self._log_event(now, "devices", f"{stream}: {listed}")
                self._say_lost(now, health, result)
                self._say_flood(now, health, result)
            kind = {"completed": "stop"}.get(result.status, result.status)
            if result.status != "failed" and self.hub.failure is not None:
                kind, result.message = "failed", f"{self.hub.failure}; the run had {result.status}: {result.message}"
            self._log_event(now, kind, result.message)
        finally:
            try:
                self.rig.close()
            finally:
                self.hub.close()
