"""Batches of samples and their fan-out from devices to sinks.

A :class:`Batch` is the one unit of data that flows through beambench: a few hundred samples of one stream,
each stamped with the host's monotonic receive time (``host_time_ns``) and the device's own clock
(``device_time``, seconds). Devices describe their streams once with a :class:`StreamSpec`, so sinks
(HDF5, Rerun, monitors) need no per-device code.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class ColumnSpec:
    """One per-sample column: its per-sample shape, dtype, unit and (optional) labels of the last axis."""

    shape: tuple[int, ...] = ()
    dtype: str = "float64"
    unit: str = ""
    labels: tuple[str, ...] = ()
    description: str = ""


@dataclass(frozen=True)
class StreamSpec:
    """What a stream produces: name, nominal rate and its columns (``data`` first by convention)."""

    name: str
    rate_hz: float
    columns: dict[str, ColumnSpec]
    device_time_unit: str = "s"
    description: str = ""

    def empty_batch(self) -> "Batch":
        """A batch with zero samples and the right column shapes."""
        cols = {k: np.zeros((0, *c.shape), dtype=c.dtype) for k, c in self.columns.items()}
        return Batch(self.name, np.zeros(0, np.int64), np.zeros(0, np.float64), cols)


@dataclass(frozen=True)
class Batch:
    """Samples of one stream: ``host_time_ns[n]``, ``device_time[n]`` and ``columns[name][n, ...]``."""

    stream: str
    host_time_ns: np.ndarray
    device_time: np.ndarray
    columns: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.host_time_ns)
        if len(self.device_time) != n:
            raise ValueError(f"{self.stream}: device_time has {len(self.device_time)} rows, expected {n}")
        for name, col in self.columns.items():
            if len(col) != n:
                raise ValueError(f"{self.stream}.{name}: {len(col)} rows, expected {n}")

    def __len__(self) -> int:
        return len(self.host_time_ns)

    @staticmethod
    def concat(batches: list["Batch"]) -> "Batch":
        """Join batches of the same stream in order."""
        if not batches:
            raise ValueError("no batches to join")
        first = batches[0]
        return Batch(
            first.stream,
            np.concatenate([b.host_time_ns for b in batches]),
            np.concatenate([b.device_time for b in batches]),
            {k: np.concatenate([b.columns[k] for b in batches]) for k in first.columns},
        )


@runtime_checkable
class Sink(Protocol):
    """Receives every batch and every event; knows nothing of the backend that produced them."""

    def open(self, specs: list[StreamSpec]) -> None: ...
    def write(self, batch: Batch) -> None: ...
    def event(self, host_time_ns: int, kind: str, message: str) -> None: ...
    def close(self) -> None: ...


class Hub:
    """Fans batches and events out to sinks; a failing sink is reported once and dropped, never fatal."""

    def __init__(self, sinks: list[Sink]) -> None:
        self.sinks = list(sinks)
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
            if hasattr(sink, "flush"):
                self._call(sink, "flush")

    def step(self, record: object) -> None:
        """A protocol step started or ended (sinks without a ``step`` method ignore it)."""
        for sink in list(self.sinks):
            if hasattr(sink, "step"):
                self._call(sink, "step", record)

    def close(self) -> None:
        for sink in list(self.sinks):
            self._call(sink, "close")

    def _call(self, sink: Sink, method: str, *args: object) -> None:
        try:
            getattr(sink, method)(*args)
        except Exception as exc:  # a broken viewer must not lose the HDF5 session
            if getattr(sink, "critical", False):
                raise
            self.errors.append(f"{type(sink).__name__}.{method}: {exc}")
            self.sinks.remove(sink)
