"""The CAN link to one ODrive node: the bus opened (or given), frames sent under one lock, every frame sent and
received written to the ``--can-log`` file, and a receive thread that hands each frame to its handler with the
time it arrived.

Receiving: one thread of the link's own (not ``can.Notifier``) waits for a frame, then lets frames gather for
:data:`RECEIVE_COALESCE_S` and handles all that wait, so ~200 frames/s cost ~50 wake-ups instead of 200 (the
stamps are the interface's receive times, :func:`receive_ns`, so the wait costs no timing accuracy; a fault read
from a heartbeat is seen at most this much later, far inside the heartbeat and poll periods).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can

from beambench.acquisition.capabilities import DeviceFault, PacksAhead
from beambench.common.oserrors import can_open_problem
from beambench.devices.odrive import cansimple as cs
from beambench.devices.odrive.can_log import LOG_SUFFIXES, TrafficLog
from beambench.devices.receive_time import mono_minus_real_ns

RECEIVE_COALESCE_S = 0.02  # after a frame arrives, let others gather this long: one wake-up handles them all
MAX_FRAMES_PER_WAKE = 1024  # a flood cannot keep the receive thread from checking its stop flag

FrameHandler = Callable[[can.Message, int], None]  # (frame, arrival on the monotonic clock, ns)


def receive_ns(frame: can.Message, now_ns: int, mono_minus_real_ns: int) -> int:
    """When ``frame`` arrived, on the monotonic clock: python-can's timestamp moved from the wall clock when it
    is one (not after ``now_ns``, at most a second before it); otherwise ``now_ns`` (an interface whose stamps
    run on another clock, or none)."""
    ts = frame.timestamp
    if ts:
        stamped = int(ts * 1e9) + mono_minus_real_ns
        if now_ns - 1_000_000_000 <= stamped <= now_ns:
            return stamped
    return now_ns


class CanLink:
    """The CAN bus as the driver of node ``node_id`` uses it. ``interface``/``channel``/``bitrate`` go to ``can.Bus``; or an open
    ``bus`` is given (then :meth:`close` shuts it down only if ``own_bus``). ``can_log``: the traffic file, or None.
    """

    def __init__(
        self,
        node_id: int,
        interface: str,
        channel: str,
        bitrate: int | None = None,
        *,
        bus: can.BusABC | None = None,
        own_bus: bool = True,
        can_log: Path | None = None,
        extended_id: bool = False,
    ) -> None:
        cs.arbitration_id(node_id, 0, extended_id)  # validates the node id
        if can_log is not None and can_log.suffix.lower() not in LOG_SUFFIXES:
            raise ValueError(f"can_log {can_log}: unknown log format (use one of {', '.join(LOG_SUFFIXES)})")
        self.node_id, self.extended_id = node_id, extended_id
        self.interface, self.channel, self.bitrate, self.can_log = interface, channel, bitrate, can_log
        self._bus = bus
        self._own_bus = own_bus
        self._log: TrafficLog | None = None
        self._tx_lock = threading.Lock()
        self._receiver: threading.Thread | None = None
        self._receiver_stop = threading.Event()
        self.closed = False  # closed for good (a given bus may stay open)
        self.tx_count = 0
        self.send_errors: deque[str] = deque(maxlen=100)  # sends that failed where no caller could be told
        self.rx_errors: deque[str] = deque(maxlen=100)  # what the receive thread met (the bus closing under it)

    @property
    def bus(self) -> can.BusABC | None:
        """The open bus (None before :meth:`open` and after :meth:`close`)."""
        return self._bus

    @property
    def receiving(self) -> bool:
        return self._receiver is not None

    def open(self, on_frame: FrameHandler, thread_name: str, keep_packed: tuple[can.Message, ...] = ()) -> None:
        """Open the bus (if not given) and the log; start handing every frame to ``on_frame``. ``keep_packed``: frames
        a bus that packs ahead (:class:`PacksAhead`) keeps ready, so sending them needs no memory later."""
        if self._bus is None:
            kwargs: dict[str, Any] = {"interface": self.interface, "channel": self.channel}
            if self.bitrate is not None:
                kwargs["bitrate"] = self.bitrate
            try:
                self._bus = can.Bus(**kwargs)
            except (can.CanError, OSError, ValueError, ImportError) as exc:
                why = can_open_problem(self.interface, self.channel, exc, self.bitrate)
                raise DeviceFault(f"cannot open CAN bus {self.interface}:{self.channel}: {why}") from exc
        if isinstance(self._bus, PacksAhead):
            for frame in keep_packed:
                self._bus.keep_packed(frame)
        if self.can_log is not None:
            self._log = TrafficLog(self.can_log)
        self._receiver_stop.clear()
        self._receiver = threading.Thread(target=self._receive_loop, args=(on_frame,), name=thread_name, daemon=True)
        self._receiver.start()

    def close(self) -> None:
        """Stop receiving, close the log (flushing it) and the bus if it is ours. Never raises."""
        self._receiver_stop.set()
        if self._receiver is not None:
            self._receiver.join(timeout=1.0)
            self._receiver = None
        if self._log is not None:
            self._log.stop()
        if self._own_bus and self._bus is not None:
            with contextlib.suppress(Exception):
                self._bus.shutdown()
            self._bus = None
        self.closed = True

    def sink_failure(self) -> str | None:
        """Why the ``--can-log`` file stopped early (a full disk), or None."""
        log = self._log
        return log.failure if log is not None else None

    def send(self, msg: can.Message) -> None:
        """Send one frame (and log it); DeviceFault if the bus is not open or refuses it."""
        if self._bus is None:
            raise DeviceFault("CAN bus is not open")
        with self._tx_lock:
            try:
                self._bus.send(msg, timeout=0.1)
            except can.CanError as exc:
                raise DeviceFault(f"CAN send failed: {exc}") from exc
            self.tx_count += 1
            if self._log is not None:
                msg.timestamp = time.time()
                msg.is_rx = False
                msg.channel = getattr(self._bus, "channel_id", None) or self.channel
                self._log(msg)

    def send_message(self, message: cs.Message) -> None:
        """Send one CAN Simple message to the node."""
        self.send(cs.to_can(self.node_id, message, self.extended_id))

    def request(self, cmd: cs.Cmd) -> None:
        """Ask the node for a get message by RTR (the answer arrives through the receive thread)."""
        self.send(cs.request(self.node_id, cmd, self.extended_id))

    def _receive_loop(self, on_frame: FrameHandler) -> None:
        """Wait for a frame, let others gather for RECEIVE_COALESCE_S, handle all that wait; until closed."""
        bus, stop = self._bus, self._receiver_stop
        assert bus is not None
        while not stop.is_set():
            try:
                frame = bus.recv(timeout=0.05)
                if frame is None:
                    continue
                stop.wait(RECEIVE_COALESCE_S)
                mono_minus_real = mono_minus_real_ns()
                now_ns = time.monotonic_ns()
                for _ in range(MAX_FRAMES_PER_WAKE):
                    if self._log is not None:
                        self._log(frame)
                    on_frame(frame, receive_ns(frame, now_ns, mono_minus_real))
                    frame = bus.recv(timeout=0.0)
                    if frame is None:
                        break
            except Exception as exc:  # e.g. the bus closing under us: recorded, never a traceback
                if stop.is_set():
                    return
                with contextlib.suppress(MemoryError):
                    self.rx_errors.append(f"{type(exc).__name__}: {exc}")
                time.sleep(0.01)  # a dead interface must not spin this thread; the heartbeat check reports it
