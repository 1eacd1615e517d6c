"""An in-memory rig on a manual clock, for testing the run's logic (runner, hub, monitors) deterministically.

Rig time moves only when the runner waits (``ManualClock.wait``): no thread, no socket, no sleep. Each stream
samples at its nominal rate on that clock, so what a run records is known exactly in advance. The drivers
themselves are tested over their real transports elsewhere; this rig stands in for a whole rig only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from beambench.acquisition.batch import Batch, StepRecord, StreamSpec
from beambench.acquisition.capabilities import DeviceFault, MotorLimits
from beambench.acquisition.streams import loadcell_spec, mocap_spec, motor_spec

NS = 1_000_000_000
START_NS = 5 * NS  # a rig clock that does not start at zero
LIMITS = MotorLimits(max_frequency_hz=20.0, max_current_a=5.0, amplitude_mm=2.0)  # what a run on it arms with


class ManualClock:
    """Host time in ns that advances only by :meth:`wait` (the runner's polls), exactly."""

    def __init__(self, start_ns: int = START_NS) -> None:
        self.t_ns = start_ns
        self.waits: list[float] = []

    def now_ns(self) -> int:
        return self.t_ns

    def wait(self, seconds: float) -> None:
        self.waits.append(seconds)
        self.t_ns += round(seconds * NS)


@dataclass
class FakeStream:
    """A stream sampled at ``spec.rate_hz`` on ``clock``: each read hands out the samples since the last one
    (sample k at ``start + k / rate``), except those inside a ``silent`` window (s from the clock's start);
    ``occluded`` windows mark every marker of a mocap sample hidden. ``fault_at_s``: from then on it fails."""

    spec: StreamSpec
    clock: ManualClock
    silent: list[tuple[float, float]] = field(default_factory=list)
    occluded: list[tuple[float, float]] = field(default_factory=list)
    fault_at_s: float | None = None
    next_k: int = 0
    started: bool = False

    @property
    def name(self) -> str:
        return self.spec.name

    def describe(self) -> StreamSpec:
        return self.spec

    def start(self) -> None:
        self.started = True

    def stop(self) -> None:
        self.started = False

    def _t(self, ns: int) -> float:
        return (ns - START_NS) / NS

    def check(self) -> None:
        if self.fault_at_s is not None and self._t(self.clock.now_ns()) >= self.fault_at_s:
            raise DeviceFault(f"{self.name}: failed at {self.fault_at_s:g} s")

    def read(self) -> Batch:
        now = self._t(self.clock.now_ns())
        last = math.floor(now * self.spec.rate_hz + 1e-9)
        ks = np.arange(self.next_k, last + 1)
        self.next_k = last + 1
        t = ks / self.spec.rate_hz
        keep = np.ones(len(t), bool)
        for a, b in self.silent:
            keep &= ~((t >= a) & (t < b))
        t = t[keep]
        host = START_NS + np.round(t * NS).astype(np.int64)
        cols = {}
        for name, c in self.spec.columns.items():
            cols[name] = np.zeros((len(t), *c.shape), dtype=c.dtype)
        if "occluded" in cols:
            hidden = np.zeros(len(t), bool)
            for a, b in self.occluded:
                hidden |= (t >= a) & (t < b)
            cols["occluded"][hidden] = True
        return Batch(self.name, host, t, cols)


@dataclass
class FakeMotor(FakeStream):
    """The drive: records every command with its rig time (s), and whether it is armed."""

    commands: list[tuple[float, str, float]] = field(default_factory=list)
    armed: MotorLimits | None = None

    def arm(self, limits: MotorLimits) -> None:
        self.armed = limits
        self.commands.append((self._t(self.clock.now_ns()), "arm", 0.0))

    def set_frequency(self, hz: float) -> None:
        self.commands.append((self._t(self.clock.now_ns()), "frequency", hz))

    def idle(self) -> None:
        self.commands.append((self._t(self.clock.now_ns()), "idle", 0.0))


class FakeRig:
    """A motor and named streams on one manual clock; ``calls`` lists open, close and the motor's commands."""

    def __init__(self, markers: tuple[str, ...] = ("stage", "tip"), **faults: Any) -> None:
        self.clock = ManualClock()
        self.motor = FakeMotor(motor_spec(), self.clock, fault_at_s=faults.pop("motor_fault_at_s", None))
        self.mocap = FakeStream(mocap_spec(markers), self.clock, **faults.pop("mocap", {}))
        self.loadcell = FakeStream(loadcell_spec(), self.clock)
        self.calls: list[str] = []

    @property
    def streams(self) -> list[FakeStream]:
        return [self.motor, self.mocap, self.loadcell]

    def open(self) -> None:
        self.calls.append("open")
        for s in self.streams:
            s.start()

    def close(self) -> None:
        self.motor.idle()  # as every rig: idle first
        self.calls.append("close")
        for s in self.streams:
            s.stop()

    def identity(self) -> dict[str, Any]:
        return {"rig": "fake"}

    def check(self) -> None:
        for s in self.streams:
            s.check()


class RecordingSink:
    """A sink that keeps everything the hub gave it: batches, events (kind, t in s) and step records."""

    label = "recording"

    def __init__(self, fail_on: Callable[[Batch], bool] | None = None) -> None:
        self.batches: list[Batch] = []
        self.events: list[tuple[str, float, str]] = []
        self.steps: dict[int, StepRecord] = {}
        self.fail_on = fail_on
        self.closed = False

    def open(self, specs: list[StreamSpec]) -> None:
        self.specs = specs

    def write(self, batch: Batch) -> None:
        if self.fail_on is not None and self.fail_on(batch):
            raise OSError("no space left on device")
        self.batches.append(batch)

    def event(self, host_time_ns: int, kind: str, message: str) -> None:
        self.events.append((kind, (host_time_ns - START_NS) / NS, message))

    def step(self, record: StepRecord) -> None:
        self.steps[record.index] = StepRecord(**vars(record))

    def close(self) -> None:
        self.closed = True

    def rows(self, stream: str) -> int:
        return sum(len(b) for b in self.batches if b.stream == stream)

    def kinds(self) -> list[str]:
        return [k for k, _, _ in self.events]
