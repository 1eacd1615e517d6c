"""Fan-out of batches and events from the runner to the sinks (HDF5 session, Rerun, monitors)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from beambench.acquisition.batch import Batch, StepRecord, StreamSpec


@runtime_checkable
class Sink(Protocol):
    """Receives every batch and every event; knows nothing of the backend that produced them."""

    def open(self, specs: list[StreamSpec]) -> None: ...
    def write(self, batch: Batch) -> None: ...
    def event(self, host_time_ns: int, kind: str, message: str) -> None: ...
    def close(self) -> None: ...


@runtime_checkable
class Flushable(Protocol):
    """A sink that buffers: ``flush`` makes everything written so far durable (end of one poll round)."""

    def flush(self) -> None: ...


@runtime_checkable
class FollowsSteps(Protocol):
    """A sink that records protocol steps as they start and end."""

    def step(self, record: StepRecord) -> None: ...


class SinkFailure(Exception):
    """A critical sink (the session file) failed: the run stops. ``sink`` names it, ``reason`` says why."""

    def __init__(self, sink: str, reason: str) -> None:
        super().__init__(f"{sink}: {reason}")
        self.sink, self.reason = sink, reason


@runtime_checkable
class Labelled(Protocol):
    """A sink that names itself in messages (``session file data/x.h5``, ``recording data/x.rrd``)."""

    label: str


def sink_label(sink: object) -> str:
    """How a sink is named in messages: its ``label``, else its type."""
    return sink.label if isinstance(sink, Labelled) else type(sink).__name__


class Hub:
    """Fans batches and events out to sinks. A failing sink is reported once and dropped, never fatal, unless
    it is one of the ``critical`` sinks (the session writer): then :class:`SinkFailure` stops the run, once.

    A failed critical sink gets no more batches (nor flushes), but still the closing records (steps, events,
    ``close``): it decides itself whether it can take them (the writer does if its space reserve held); any
    further error of it is only recorded. The other sinks go on."""

    def __init__(self, sinks: list[Sink], critical: tuple[Sink, ...] = ()) -> None:
        self.sinks = list(sinks)
        self.critical = tuple(critical)
        self.errors: list[str] = []
        self.counts: dict[str, int] = {}
        self.failure: SinkFailure | None = None  # the first critical sink's failure
        self._failed: list[Sink] = []  # critical sinks that failed: closing records only

    def open(self, specs: list[StreamSpec]) -> None:
        for s in specs:
            self.counts.setdefault(s.name, 0)
        for sink in list(self.sinks):
            self._call(sink, "open", specs)

    def write(self, batch: Batch) -> None:
        if len(batch) == 0:
            return
        self.counts[batch.stream] = self.counts.get(batch.stream, 0) + len(batch)
        for sink in list(self.sinks):
            if not self._is_failed(sink):
                self._call(sink, "write", batch)

    def event(self, host_time_ns: int, kind: str, message: str = "") -> None:
        for sink in list(self.sinks):
            self._call(sink, "event", host_time_ns, kind, message)

    def flush(self) -> None:
        """End of one poll round: sinks that buffer (the HDF5 writer) make everything so far durable."""
        for sink in list(self.sinks):
            if isinstance(sink, Flushable) and not self._is_failed(sink):
                self._call(sink, "flush")

    def step(self, record: StepRecord) -> None:
        """A protocol step started or ended (sinks that do not follow steps ignore it)."""
        for sink in list(self.sinks):
            if isinstance(sink, FollowsSteps):
                self._call(sink, "step", record)

    def close(self) -> None:
        """Close every sink (a failing close is recorded, never raised: each sink gets its close)."""
        for sink in list(self.sinks):
            self._call(sink, "close", raise_failure=False)

    def _is_failed(self, sink: Sink) -> bool:
        return any(sink is f for f in self._failed)

    def _call(self, sink: Sink, method: str, *args: object, raise_failure: bool = True) -> None:
        try:
            getattr(sink, method)(*args)
        except Exception as exc:  # a broken viewer must not lose the HDF5 session
            reason = str(exc) or type(exc).__name__
            critical = any(sink is c for c in self.critical)
            if critical and method == "open":
                raise  # nothing ran yet: the sink's own error (e.g. the session file exists)
            if not critical:
                self.errors.append(f"{sink_label(sink)} ({method}): {reason}")
                self.sinks.remove(sink)
                return
            if self._is_failed(sink):  # the same failure again (a closing record it could not take): said once
                return
            self._failed.append(sink)
            failure = SinkFailure(sink_label(sink), reason)
            self.failure = self.failure or failure
            if raise_failure:
                raise failure from None
