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


class Hub:
    """Fans batches and events out to sinks. A failing sink is reported once and dropped, never fatal, unless
    it is one of the ``critical`` sinks (the session writer): then the error stops the run."""

    def __init__(self, sinks: list[Sink], critical: tuple[Sink, ...] = ()) -> None:
        self.sinks = list(sinks)
        self.critical = tuple(critical)
        self.errors: list[str] = []
        self.counts: dict[str, int] = {}

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
            self._call(sink, "write", batch)

    def event(self, host_time_ns: int, kind: str, message: str = "") -> None:
        for sink in list(self.sinks):
            self._call(sink, "event", host_time_ns, kind, message)

    def flush(self) -> None:
        """End of one poll round: sinks that buffer (the HDF5 writer) make everything so far durable."""
        for sink in list(self.sinks):
            if isinstance(sink, Flushable):
                self._call(sink, "flush")

    def step(self, record: StepRecord) -> None:
        """A protocol step started or ended (sinks that do not follow steps ignore it)."""
        for sink in list(self.sinks):
            if isinstance(sink, FollowsSteps):
                self._call(sink, "step", record)

    def close(self) -> None:
        for sink in list(self.sinks):
            self._call(sink, "close")

    def _call(self, sink: Sink, method: str, *args: object) -> None:
        try:
            getattr(sink, method)(*args)
        except Exception as exc:  # a broken viewer must not lose the HDF5 session
            if any(sink is c for c in self.critical):
                raise
            self.errors.append(f"{type(sink).__name__}.{method}: {exc}")
            self.sinks.remove(sink)
