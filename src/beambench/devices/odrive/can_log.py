"""The ``--can-log`` file: every CAN frame sent and received, through python-can's writers, in one of
:data:`LOG_SUFFIXES` (read by the input checks without loading python-can: it is imported when a log opens).
A sink like the session file: a write that fails (a full disk) stops the logging and is reported
(:attr:`TrafficLog.failure`), never silently truncated and never raised into the receive thread or a send."""

from __future__ import annotations

import contextlib
import copy
import threading
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import can

LOG_SUFFIXES = (".asc", ".blf", ".log", ".trc", ".csv")  # python-can writers that keep direction or ids


class TrafficLog:
    """python-can's ``can.Logger`` shared by the receive thread (received) and senders (sent), locked."""

    def __init__(self, path: str | Path) -> None:
        import can

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._writer = can.Logger(str(self.path))
        self._channel_number = can.util.channel2int
        self._lock = threading.Lock()
        self._closed = False
        self.failure: str | None = None  # why the log stopped early (its file holds the frames before)

    def on_message_received(self, msg: can.Message) -> None:
        number = self._channel_number(msg.channel)
        if msg.channel is not None and (number is None or not 0 <= number < 0xFFFF):
            # .blf stores the channel as a 16-bit number read off the name's trailing digits; a name such as
            # a virtual bus "odrive-…93817" would overflow it: log such frames on the file's default channel
            msg = copy.copy(msg)
            msg.channel = None
        with self._lock:
            if self._closed:
                return
            try:
                self._writer.on_message_received(msg)
            except (OSError, ValueError) as exc:
                self._fail(exc)

    __call__ = on_message_received

    def _fail(self, exc: Exception) -> None:
        """A write failed: keep why, stop writing (the lock is held)."""
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        self.failure = f"CAN log {self.path}: {why}"
        self._closed = True
        with contextlib.suppress(Exception):
            self._writer.stop()

    def stop(self) -> None:
        """Flush and close; a failure doing so is kept in :attr:`failure`."""
        with self._lock:
            if not self._closed:
                self._closed = True
                try:
                    self._writer.stop()
                except (OSError, ValueError) as exc:
                    self._fail(exc)
