"""What every stream driver rewrites, written once: lifecycle, reader thread, row buffer, counters, liveness.

In the spirit of python-can's ``BusABC`` (a small base that owns the lifecycle — idempotent shutdown, a context
manager — and leaves the wire to subclasses), :class:`StreamDriver` gives a driver:

- ``start()`` / ``stop()``: idempotent; ``stop()`` is safe from any state, also after a failed ``start()``;
  ``with driver:`` starts and always stops;
- an optional reader thread that calls the subclass's :meth:`~StreamDriver._receive` until stopped; an
  exception there is kept as the driver's fault (reported by :meth:`check` and :meth:`read`), never lost;
- a row buffer: the reader appends rows with :meth:`~StreamDriver._push` (which stamps the last-receive time),
  :meth:`read` takes them all and hands them to the subclass's :meth:`~StreamDriver._to_batch`;
- :class:`Counters`: received, dropped (the device sent it, it never arrived), garbled (arrived, failed to
  decode), forged (arrived from a sender that is not the device);
- liveness: :meth:`check` raises :class:`DeviceFault` on a fault, or when nothing arrived for longer than
  ``silence_timeout_s`` while running and listening (a reader thread that got no CPU, e.g. a suspended host, does
  not make its device silent: its data wait on the wire). :meth:`read` returns what arrived; only when nothing
  did and the device is faulty or silent does it raise, so samples received before a failure are never lost.

Subclasses implement ``_open``, ``_close``, ``_receive`` (one bounded wait for data), ``_to_batch`` and, if a
blocking receive must be woken to stop, ``_interrupt``.
"""

from __future__ import annotations

import contextlib
import threading
import time
from dataclasses import asdict, dataclass
from typing import Any

from beambench.acquisition.batch import Batch, StreamSpec
from beambench.acquisition.capabilities import DeviceFault

# A reader thread that has not come back from a (short, bounded) receive for this many silence timeouts is hung,
# not merely starved: its device is then judged on the host's clock (StreamDriver._listened_until)
READER_HUNG_TIMEOUTS = 10.0

__all__ = ["Counters", "StreamDriver"]


@dataclass
class Counters:
    """What a driver saw on its wire, for ``/general/devices/<stream>`` and the event log."""

    received: int = 0  # samples (frames, rows) received (``unrecorded`` in health(): those never read)
    dropped: int = 0  # samples the device sent that never arrived (gaps in its numbering), or a full buffer evicted
    garbled: int = 0  # frames, datagrams or stretches of bytes that arrived but failed to decode (CRC, parse, noise)
    forged: int = 0  # datagrams from a sender that is not the device the handshake found

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class StreamDriver:
    """Base of the stream drivers; see the module docstring. ``name`` and ``describe()`` make it a Stream."""

    name: str
    reader_thread = True  # False: the subclass receives some other way (a client's own thread)

    def __init__(self, name: str, spec: StreamSpec, silence_timeout_s: float | None = 0.5) -> None:
        self.name = name
        self.where = ""  # the port or address the device is on, for the fault messages ("" if none)
        self._spec = spec
        self.silence_timeout_s = silence_timeout_s
        self.counters = Counters()
        self._lock = threading.Lock()
        self._rows: list[Any] = []
        self._stop_evt = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = False
        self._started_ns: int | None = None
        self._fault: str | None = None
        self._fault_reported = False
        self.last_receive_ns: int | None = None
        self._awake_ns: int | None = None  # when the reader thread last came back from a receive

    # -- to implement --------------------------------------------------------------------------------------
    def _open(self) -> None:
        """Connect (open the port, the socket). Raise :class:`DeviceFault` if the device cannot be reached."""

    def _close(self) -> None:
        """Release what ``_open`` took. Never raises."""

    def _interrupt(self) -> None:
        """Wake a ``_receive`` blocked on the wire (called by ``stop`` before joining the thread)."""

    def _receive(self) -> None:
        """Wait a short, bounded time for data and ``_push`` what arrived (reader thread only)."""
        raise NotImplementedError

    def _to_batch(self, rows: list[Any]) -> Batch:
        """The rows taken from the buffer, as one Batch of this stream (never called with no rows)."""
        raise NotImplementedError

    # -- Stream --------------------------------------------------------------------------------------------
    def describe(self) -> StreamSpec:
        return self._spec

    def start(self) -> None:
        """Open and start receiving. Idempotent; on failure everything opened is closed again."""
        if self._started:
            return
        self._reset()
        self._stop_evt.clear()
        try:
            self._open()
        except BaseException:
            self._close()
            raise
        self._started = True
        self._started_ns = self._awake_ns = time.monotonic_ns()
        if self.reader_thread:
            self._thread = threading.Thread(target=self._reader, name=f"{self.name}-reader", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop the reader and close. Idempotent, never raises; what was received stays readable."""
        self._stop_evt.set()
        was = self._started
        self._started = False
        with contextlib.suppress(Exception):
            self._interrupt()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        if was:
            with contextlib.suppress(Exception):
                self._close()

    def close(self) -> None:
        self.stop()

    def __enter__(self) -> StreamDriver:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def read(self) -> Batch:
        """Everything received since the last call. With nothing received, raise :class:`DeviceFault` if the
        device failed or has been silent longer than ``silence_timeout_s``; else an empty batch."""
        with self._lock:
            rows, self._rows = self._rows, []
        if rows:
            return self._to_batch(rows)
        if not self._fault_reported:
            try:
                self.check()
            except DeviceFault:
                self._fault_reported = True  # once: the final drain after the idle must not fail again
                raise
        return self._spec.empty_batch()

    # -- health --------------------------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self._started and (not self.reader_thread or (self._thread is not None and self._thread.is_alive()))

    def check(self) -> None:
        """Raise :class:`DeviceFault` if the device failed, or sent nothing for ``silence_timeout_s``. A fault
        raised here counts as reported: :meth:`read` then does not raise it again (the runner's final drain
        after the idle must not fail on the fault that stopped the run, whichever call found it first)."""
        try:
            self._check_health()
        except DeviceFault:
            self._fault_reported = True
            raise

    def _check_health(self) -> None:
        if self._fault is not None:
            raise DeviceFault(f"{self.name}: {self._fault}")
        timeout = self.silence_timeout_s
        if timeout is None or not self._started or self._started_ns is None:
            return
        last = self.last_receive_ns if self.last_receive_ns is not None else self._started_ns
        silent = self._listened_until(time.monotonic_ns(), timeout) - last
        if silent > timeout * 1e9:
            what = "nothing received" if self.last_receive_ns is None else "silent"
            on = f" on {self.where}" if self.where else ""
            raise DeviceFault(f"{self.name}{on}: {what} for {silent * 1e-9:.2f} s (> {timeout:g} s)")

    def _listened_until(self, now_ns: int, timeout_s: float) -> int:
        """Up to when the device had the chance to be heard: the reader thread's last return from a receive, not
        ``now_ns``, while that is recent (a host that stalled, e.g. suspended or starved of CPU, left the reader
        asleep with the device's data waiting on the wire: the device was not silent). A reader asleep for over
        :data:`READER_HUNG_TIMEOUTS` timeouts is hung: then ``now_ns``. Without a reader thread: ``now_ns``."""
        awake = self._awake_ns
        if not self.reader_thread or awake is None or now_ns - awake > READER_HUNG_TIMEOUTS * timeout_s * 1e9:
            return now_ns
        return awake

    def health(self) -> dict[str, Any]:
        """The counters, the fault if any, and the age of the last sample (s), for the session. ``unrecorded``: rows
        received but never handed out by :meth:`read` (they arrived after the run's last read, while it closed),
        so every row received is either in the session or counted here: ``received - unrecorded`` rows stored."""
        last = self.last_receive_ns
        return {
            **self.counters.as_dict(),
            "unrecorded": self._unrecorded(),
            "fault": self._fault or "",
            "silence_timeout_s": self.silence_timeout_s if self.silence_timeout_s is not None else float("nan"),
        } | ({"last_receive_age_s": (time.monotonic_ns() - last) * 1e-9} if last is not None else {})

    def _unrecorded(self) -> int:
        """Rows received and still waiting for :meth:`read` (see :meth:`health`)."""
        with self._lock:
            return len(self._rows)

    # -- for subclasses ------------------------------------------------------------------------------------
    def _reset(self) -> None:
        """Forget the previous run (buffer, fault, last receive); counters start again from zero."""
        with self._lock:
            self._rows = []
        self._fault = None
        self._fault_reported = False
        self.last_receive_ns = None
        self.counters = Counters()

    def _push(self, rows: list[Any], host_ns: int) -> None:
        """Rows that arrived at ``host_ns`` (monotonic ns): buffered, counted, and the stream is alive."""
        if not rows:
            return
        with self._lock:
            self._rows.extend(rows)
            self.counters.received += len(rows)
            self.last_receive_ns = host_ns

    def _set_fault(self, message: str) -> None:
        if self._fault is None:
            self._fault = message

    def _reader(self) -> None:
        try:
            while not self._stop_evt.is_set():
                self._receive()
                self._awake_ns = time.monotonic_ns()
        except Exception as exc:  # the wire failed: kept, reported by check()/read(), never swallowed
            if not self._stop_evt.is_set():
                self._set_fault(self._failure(exc))

    def _failure(self, exc: Exception) -> str:
        """The fault text for an exception of the reader thread."""
        return f"{type(exc).__name__}: {exc}"
