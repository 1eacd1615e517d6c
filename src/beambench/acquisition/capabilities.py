"""The device seams: small structural Protocols, one per capability, that sim, emulated and hardware rigs satisfy.

No base class is required (as in bluesky's ``protocols.py``): anything with these methods is a device.
The runner and the sinks only ever see these Protocols, so they cannot tell the backends apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from beambench.acquisition.batch import Batch, StreamSpec
from beambench.common.errors import BeambenchError


class DeviceFault(BeambenchError, RuntimeError):
    """A device reported an error or went silent; the runner idles the motor and saves what it has."""


@dataclass(frozen=True)
class MotorLimits:
    """Limits enforced before anything moves (from the protocol's ``limits`` block)."""

    max_frequency_hz: float
    max_current_a: float
    amplitude_mm: float


@runtime_checkable
class Clock(Protocol):
    """The rig's clock. On hardware it is wall time; on the sim backend waiting advances the physics."""

    def now_ns(self) -> int:
        """Host monotonic time in nanoseconds (simulated host time on the sim backend)."""
        ...

    def wait(self, seconds: float) -> None:
        """Let ``seconds`` of rig time pass (sleep on hardware, step the physics in simulation)."""
        ...


@runtime_checkable
class Stream(Protocol):
    """A source of time-stamped samples, read as :class:`Batch` objects."""

    name: str

    def describe(self) -> StreamSpec: ...

    def start(self) -> None: ...

    def read(self) -> Batch:
        """Everything received since the last call (possibly zero rows); never blocks for long. With nothing
        to hand out, raises :class:`DeviceFault` if the device failed or is silent (as :meth:`check`)."""
        ...

    def stop(self) -> None: ...

    def check(self) -> None:
        """Raise :class:`DeviceFault` if the device failed or sent nothing for longer than its timeout."""
        ...


@runtime_checkable
class ReportsHealth(Protocol):
    """A driver that counts what its wire did: ``received``, ``dropped``, ``garbled``, ``forged`` (and more),
    stored in the session under ``/general/devices/<stream>``."""

    def health(self) -> dict[str, Any]: ...


@runtime_checkable
class RefusesForeign(Protocol):
    """A transport that accepts only its device's endpoint: ``forged`` datagrams came from any other sender,
    ``garbled`` ones from the device but were no frame, ``kernel_dropped`` ones the kernel dropped unread (its
    buffer full); :meth:`flood` names a flood (the emulated rig's loopback CAN bus)."""

    forged: int
    garbled: int
    kernel_dropped: int

    def flood(self) -> str:
        """``flood: N datagrams from host:port dropped …`` when the transport was flooded, else ""."""
        ...


@runtime_checkable
class PacksAhead(Protocol):
    """A transport that encodes a message once, ahead of sending it: sending it later needs no memory."""

    def keep_packed(self, msg: Any) -> None: ...


@runtime_checkable
class Motor(Stream, Protocol):
    """The drive: crank speed f turn/s gives the stage x = A·sin(2πft). Also a telemetry stream."""

    def arm(self, limits: MotorLimits) -> None:
        """Apply limits (velocity, current), enter closed-loop velocity control at 0 turn/s."""
        ...

    def set_frequency(self, hz: float) -> None: ...

    def idle(self) -> None:
        """Command the motor to idle. Idempotent and safe from any state, including after a fault."""
        ...

    def check(self) -> None:
        """Raise :class:`DeviceFault` if the motor reports an error or its heartbeat was lost."""
        ...


@runtime_checkable
class ConfirmsIdle(Protocol):
    """A motor that reports its own state: after ``idle()``, whether the device confirms it is idle."""

    def confirm_idle(self) -> str:
        """ "motor idle …" once the device says so, else "motor idle NOT confirmed; …" (what idles it then)."""
        ...


@runtime_checkable
class ReportsSinkFailure(Protocol):
    """A device that writes a file of its own (the CAN traffic log): why that file stopped early, or None."""

    def sink_failure(self) -> str | None: ...


@runtime_checkable
class Rig(Protocol):
    """A set of devices built from a protocol and rig file: one motor, its streams and a clock."""

    # read-only members (properties), so a rig may hold a more specific clock or motor (SimClock, SimMotor)
    @property
    def clock(self) -> Clock: ...

    @property
    def motor(self) -> Motor: ...

    @property
    def streams(self) -> list[Stream]:
        """Every stream, the motor's telemetry included."""
        ...

    def open(self) -> None: ...

    def close(self) -> None:
        """Release every device; idles the motor first. Idempotent."""
        ...

    def identity(self) -> dict[str, Any]:
        """Device identities (serials, firmware, versions, model parameters) for ``/general``."""
        ...


@runtime_checkable
class ChecksDevices(Protocol):
    """A rig that checks every device at once: the motor, then each stream (liveness, faults). The runner
    calls it after each poll, where it calls ``motor.check()`` today."""

    def check(self) -> None: ...


@runtime_checkable
class Anticipates(Protocol):
    """A rig that can compute ahead (the sim rig's physics). The runner tells it, once armed, what the run will do
    if nothing stops or pauses it: each step's motor frequency and the ``clock.wait`` durations that follow that
    command, in order. Only a hint: the run may then do otherwise (stop, pause a record window), and the rig must
    carry on from its state at that point."""

    def anticipate(self, schedule: list[tuple[float, list[float]]]) -> None: ...


@runtime_checkable
class ReportsComputedAhead(Protocol):
    """A rig that computes the announced run ahead, possibly in parallel parts (the sim rig's segments): how far,
    so progress counts every part's work and not only what the runner has taken so far."""

    def computed_ahead(self) -> tuple[float, int] | None:
        """(seconds of rig time computed since the announced schedule began, over every part; steps whose rows are
        all computed), or None when nothing is being computed ahead."""
        ...


@runtime_checkable
class HasSilenceTimeouts(Protocol):
    """A rig whose streams each have a silence timeout (s) from the rig file, watched by a monitor per stream."""

    def silence_timeouts(self) -> dict[str, float]: ...


@runtime_checkable
class ReportsDeviceHealth(Protocol):
    """A rig whose drivers count what they received, dropped, garbled or refused as forged, by stream name."""

    def device_health(self) -> dict[str, dict[str, Any]]: ...


@runtime_checkable
class HasIdleTail(Protocol):
    """A rig whose devices keep reporting after the idle command: record ``idle_tail_s`` more to see it stop."""

    idle_tail_s: float


@runtime_checkable
class ReportsAfterRun(Protocol):
    """A rig that learns things only during the run (the NatNet ECHO table, every driver's counters:
    ``devices: {stream: {received, dropped, garbled, forged, ...}}``) and adds them to ``/general``."""

    def after_run(self) -> dict[str, Any]: ...


@runtime_checkable
class WarnsOfModel(Protocol):
    """A simulated rig or scene that knows, before it runs, that its model cannot stand for the real thing (the
    physical twin's walker on legs that fold): one sentence each, said with the run's result and by the dry run."""

    def model_warnings(self) -> list[str]: ...


@runtime_checkable
class HasSilenceTimeout(Protocol):
    """A stream that faults after ``silence_timeout_s`` without data (None: never), from the rig file."""

    silence_timeout_s: float | None


@runtime_checkable
class ReportsEchoes(Protocol):
    """A mocap driver that timed its server's clock by echo requests (NatNet ECHO): the table of host send and
    receive times and server ticks with the server's clock frequency, or None while it knows no server clock."""

    def echo_sync(self) -> dict[str, Any] | None: ...


@runtime_checkable
class Identifies(Protocol):
    """A device that says what it is (serial, firmware, wiring) for ``/general``."""

    def identity(self) -> dict[str, Any]: ...


@runtime_checkable
class Connectable(Protocol):
    """A device with a connection to open before use and close after (a CAN bus, a USB handle)."""

    def open(self) -> None: ...

    def close(self) -> None: ...
