"""Monitors: sinks that watch the batches going by and tell the runner when a step's recording must pause.

A monitor is a hub sink (it sees every batch) with one more method, ``problem(now_ns)``: a
:class:`Problem` (a short reason, and since when the data are unusable) or None. The runner asks after every poll of the
record window; while there is a problem the window's clock stops (the step records longer), and a pause
longer than the protocol's ``monitors.max_pause_s`` stops the run like a device fault (motor idle first,
then everything recorded is saved).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, NamedTuple, Protocol

import numpy as np

from beambench.acquisition.batch import Batch, StreamSpec
from beambench.acquisition.streams import MOCAP

if TYPE_CHECKING:
    from beambench.acquisition.protocol.schema import Protocol as ProtocolConfig


class Problem(NamedTuple):
    reason: str
    since_ns: int  # host time from which the data are unusable


class Monitor(Protocol):
    name: str

    def problem(self, now_ns: int) -> Problem | None: ...


class _StreamWatch:
    """What every stream monitor shares: the stream it watches (checked on open), its timeout, when watching
    began (the grace period before the first sample) and how long the stream has been unusable."""

    name = "stream_watch"

    def __init__(self, stream: str, timeout_s: float) -> None:
        self.stream = stream
        self.timeout_ns = int(timeout_s * 1e9)
        self._since_ns: int | None = None  # when watching started

    def open(self, specs: list[StreamSpec]) -> None:
        if not any(s.name == self.stream for s in specs):
            raise ValueError(f"monitor {self.name}: no {self.stream!r} stream to watch")

    def event(self, host_time_ns: int, kind: str, message: str) -> None:
        pass

    def close(self) -> None:
        pass

    def _silent(self, now_ns: int, last_good_ns: int | None) -> tuple[int, int] | None:
        """(nanoseconds without good data, the last good time) once that exceeds the timeout, else None."""
        if self._since_ns is None:
            self._since_ns = now_ns
        last = last_good_ns if last_good_ns is not None else self._since_ns
        silent = now_ns - last
        return (silent, last) if silent > self.timeout_ns else None


class MocapLost(_StreamWatch):
    """Mocap is lost when no *complete* frame (every marker seen) arrived for ``timeout_s`` of host time:
    Motive stopped streaming, the network dropped out, or a marker is hidden."""

    name = "mocap_lost"

    def __init__(self, timeout_s: float, stream: str = MOCAP) -> None:
        super().__init__(stream, timeout_s)
        self.last_complete_ns: int | None = None
        self.last_any_ns: int | None = None

    def write(self, batch: Batch) -> None:
        if batch.stream != self.stream or not len(batch):
            return
        self.last_any_ns = int(batch.host_time_ns[-1])
        occluded = batch.columns.get("occluded")
        n = len(batch)
        complete = np.ones(n, bool) if occluded is None else ~np.asarray(occluded).reshape(n, -1).any(axis=1)
        if complete.any():
            self.last_complete_ns = int(batch.host_time_ns[np.flatnonzero(complete)[-1]])

    def problem(self, now_ns: int) -> Problem | None:
        found = self._silent(now_ns, self.last_complete_ns)
        if found is None:
            return None
        silent, last = found
        if self.last_any_ns is not None and now_ns - self.last_any_ns <= self.timeout_ns:
            return Problem(f"mocap: a marker hidden for {silent * 1e-9:.2f} s", last)
        return Problem(f"mocap lost: no frame for {silent * 1e-9:.2f} s", last)


class StreamSilent(_StreamWatch):
    """A stream is silent when none of its samples arrived for ``timeout_s`` of host time (a board stopped, a
    cable is out). The monitor pauses the record window; the driver's own ``check()`` (same kind of timeout,
    see :mod:`beambench.devices.base`) turns a long silence into a device fault."""

    def __init__(self, stream: str, timeout_s: float) -> None:
        super().__init__(stream, timeout_s)
        self.name = f"{stream}_silent"
        self.last_ns: int | None = None

    def write(self, batch: Batch) -> None:
        if batch.stream == self.stream and len(batch):
            self.last_ns = int(batch.host_time_ns[-1])

    def problem(self, now_ns: int) -> Problem | None:
        found = self._silent(now_ns, self.last_ns)
        if found is None:
            return None
        silent, last = found
        return Problem(f"{self.stream}: no sample for {silent * 1e-9:.2f} s", last)


def build_monitors(
    protocol: ProtocolConfig, streams: list[str], silence_s: Mapping[str, float] | None = None
) -> list[MocapLost | StreamSilent]:
    """The monitors a protocol asks for (``monitors:`` block), for the streams the rig has; with ``silence_s``
    (stream name → timeout, e.g. the rig file's ``silence_timeout_s``), a :class:`StreamSilent` per stream."""
    timeout = protocol.monitors.mocap_lost_s
    out: list[MocapLost | StreamSilent] = [MocapLost(timeout)] if timeout is not None and MOCAP in streams else []
    for name, seconds in (silence_s or {}).items():
        if name in streams and seconds is not None:
            out.append(StreamSilent(name, seconds))
    return out
