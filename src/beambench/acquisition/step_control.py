"""How the runner drives a step: a per-step strategy (a fixed frequency, or one a controller picks as data arrive).

:class:`~beambench.acquisition.runner.Runner` owns the life cycle and the safety (arm, steps, settle and record
windows, monitors, stop requests, idle on every exit path); a :class:`StepControl` only says which frequency to
command: at a step's start, and after every poll of rig time. :class:`FixedFrequency` (a sweep's step) commands
the step's frequency once; speed tracking
(:class:`~beambench.acquisition.control.tracking_control.SpeedTracking`) commands what its controller decides.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from beambench.acquisition.capabilities import DeviceFault, MotorLimits
from beambench.acquisition.protocol.plan import Step, step_name


@dataclass(frozen=True)
class StepStart:
    """How a step begins: the frequency its ``/steps`` row carries, the one to command now (None: none before the
    first poll) and the ``step`` event's message."""

    frequency_hz: float
    command_hz: float | None
    message: str


@runtime_checkable
class StepControl(Protocol):
    """The runner's per-step strategy."""

    closed_loop: bool  # the frequencies depend on the data: nothing can be computed ahead (no schedule)

    def check(self, steps: list[Step], limits: MotorLimits) -> None:
        """Before anything moves: raise :class:`DeviceFault` (one line) for a step the limits do not allow."""
        ...

    def start(self, step: Step, now_ns: int) -> StepStart:
        """A step begins at ``now_ns``."""
        ...

    def tick(self, step: Step, now_ns: int) -> float:
        """After a poll of the step, at ``now_ns``: the frequency to command now (the runner sends only changes)."""
        ...


class FixedFrequency:
    """A sweep's step: its own frequency from its start to its end."""

    closed_loop = False

    def __init__(self) -> None:
        self._total: int | None = None  # the plan's length, for step names ("step 51 of 80 (index 50)")

    def check(self, steps: list[Step], limits: MotorLimits) -> None:
        self._total = len(steps)
        for s in steps:
            if not 0 <= s.frequency_hz <= limits.max_frequency_hz:
                name = step_name(s.index, self._total)
                raise DeviceFault(f"{name}: {s.frequency_hz} Hz outside 0..{limits.max_frequency_hz} Hz")

    def start(self, step: Step, now_ns: int) -> StepStart:
        message = f"{step_name(step.index, self._total)}: {step.frequency_hz:g} Hz"
        return StepStart(step.frequency_hz, step.frequency_hz, message)

    def tick(self, step: Step, now_ns: int) -> float:
        return step.frequency_hz
