"""Load-cell plate driver: the MCU's serial frames (see :mod:`beambench.devices.loadcell.protocol`) as a Stream.

A reader thread reads the port with pyserial, feeds a :class:`StreamDecoder` and queues the frames, stamped
with ``time.monotonic_ns()`` when their bytes arrived (every frame of one read shares that receive time).
:meth:`SerialLoadCells.read` hands out everything queued as one :class:`~beambench.acquisition.batch.Batch` of
:func:`beambench.acquisition.streams.loadcell_spec`: ``device_time`` is the MCU microsecond clock in seconds, and ``seq`` and
``sync_edges`` are unwrapped from 32 bits, across batches. Bad bytes are counted, never raised; only a port
that fails or disappears raises :class:`~beambench.acquisition.capabilities.DeviceFault` (from ``read`` once the samples
received before the failure are handed out, or from :meth:`check`).
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import serial

from beambench.acquisition.batch import Batch
from beambench.acquisition.capabilities import DeviceFault
from beambench.acquisition.streams import LOADCELL, LOADCELL_RATE_HZ, loadcell_spec
from beambench.common.oserrors import serial_open_problem
from beambench.devices.base import StreamDriver
from beambench.devices.loadcell.protocol import CRC_NAME, FRAME_LEN, VERSION, Frame, StreamDecoder

DEFAULT_BAUDRATE = 921_600
# After the first bytes arrive the reader waits this long and reads everything then waiting: at 1 kHz a wake-up
# per sample costs more CPU than decoding it (reader thread 7.0 % of a core per sample, 1.8 % at 20 ms). Samples carry the board's own microsecond clock (t_us), which is
# what sync uses; the host time of a read only bounds it.
READ_COALESCE_S = 0.020
_U32 = 1 << 32


class Unwrap32:
    """Unwraps a 32-bit counter into int64, carrying its state across calls (steps of < 2**31 either way)."""

    def __init__(self) -> None:
        self.last_raw: int | None = None
        self.last: int = 0

    def __call__(self, raw: np.ndarray) -> np.ndarray:
        raw = np.asarray(raw, dtype=np.int64)
        if len(raw) == 0:
            return raw
        prev = raw[0] if self.last_raw is None else self.last_raw
        start = raw[0] if self.last_raw is None else self.last
        steps = np.diff(raw, prepend=prev) % _U32
        steps[steps >= _U32 // 2] -= _U32
        out = start + np.cumsum(steps)
        self.last_raw, self.last = int(raw[-1]), int(out[-1])
        return out


@dataclass
class LoadCellPing:
    """What :meth:`SerialLoadCells.ping` found on a port."""

    port: str
    ok: bool
    frames: int = 0
    version: int | None = None
    rate_hz: float | None = None  # on the MCU clock
    host_rate_hz: float | None = None
    stats: dict[str, Any] = field(default_factory=dict)
    error: str = ""

    def summary(self) -> str:
        if not self.ok:
            return f"load cells on {self.port}: not found ({self.error})"
        return (
            f"load cells on {self.port}: protocol v{self.version}, {self.rate_hz:.1f} Hz on the MCU clock "
            f"({self.frames} frames; {self.stats.get('crc_errors', 0)} CRC errors, "
            f"{self.stats.get('lost_frames', 0)} lost)"
        )


MAX_LOST_FRACTION = 0.05  # of the frames expected in one window: more is a fault that stops the run
LOST_WINDOW_FRAMES = 1000  # frames expected (received + lost) per window: 1 s at 1 kHz


class SerialLoadCells(StreamDriver):
    """The load-cell plate on a serial port (a device path or any pyserial URL, e.g. ``socket://host:port``).

    ``silence_timeout_s``: :meth:`check` (and :meth:`read` with nothing to hand out) raise :class:`DeviceFault`
    once no frame arrived for this long (the board stopped, the cable is out); ``None`` switches it off.
    """

    def __init__(
        self,
        port: str,
        baudrate: int = DEFAULT_BAUDRATE,
        *,
        name: str = LOADCELL,
        rate_hz: float = LOADCELL_RATE_HZ,
        read_timeout_s: float = 0.05,
        exclusive: bool = True,
        silence_timeout_s: float | None = 1.0,
        max_lost_fraction: float | None = MAX_LOST_FRACTION,
    ) -> None:
        super().__init__(name, loadcell_spec(rate_hz), silence_timeout_s)
        self.port = self.where = port
        self.baudrate = baudrate
        self.rate_hz = rate_hz
        self._timeout = read_timeout_s
        self._exclusive = exclusive
        self.max_lost_fraction = max_lost_fraction  # of a window's expected frames; None: losses only counted
        self._ser: serial.SerialBase | None = None
        self._reset()

    def _reset(self) -> None:
        super()._reset()
        self.decoder = StreamDecoder()
        self._t = Unwrap32()
        self._seq = Unwrap32()
        self._edges = Unwrap32()
        self.samples_delivered = 0
        self._window = (0, 0)  # (received, dropped) when the current loss window began

    @property
    def last_frame_ns(self) -> int | None:
        return self.last_receive_ns

    # -- StreamDriver ------------------------------------------------------------------------------------
    def _open(self) -> None:
        """Open the port. Raises :class:`DeviceFault` if it cannot open."""
        try:
            self._ser = serial.serial_for_url(
                self.port, baudrate=self.baudrate, timeout=self._timeout, exclusive=self._exclusive
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            why = serial_open_problem(exc)
            raise DeviceFault(f"{self.name}: cannot open serial port {self.port}: {why}") from exc

    def _interrupt(self) -> None:
        ser = self._ser
        if ser is not None and hasattr(ser, "cancel_read"):
            ser.cancel_read()

    def _close(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            with contextlib.suppress(Exception):
                ser.close()

    def _receive(self) -> None:
        ser = self._ser
        assert ser is not None
        data = ser.read(max(1, ser.in_waiting))
        if not data:
            return
        time.sleep(READ_COALESCE_S)  # one wake-up per few ms of samples, not one per sample
        data += ser.read(ser.in_waiting)
        now = time.monotonic_ns()
        with self._lock:
            frames = self.decoder.feed(data)
            st = self.decoder.stats
            self.counters.dropped = st.lost_frames
            # every stretch of bytes that was no frame (a CRC error or a truncated frame is one), and every
            # frame of a version this driver does not read
            self.counters.garbled = st.junk_runs + st.unsupported
        self._push([(now, f) for f in frames], now)

    def _failure(self, exc: Exception) -> str:
        return f"serial port {self.port} failed: {type(exc).__name__}: {exc}"

    def _to_batch(self, rows: list[tuple[int, Frame]]) -> Batch:
        n = len(rows)
        # one pass over the rows into one table (host, seq, t_us, 4 counts, edges), then columns
        table = np.array([(h, f.seq, f.t_us, *f.counts, f.sync_edges) for h, f in rows], dtype=np.int64)
        host = table[:, 0].copy()
        seq, t_us, edges = self._seq(table[:, 1]), self._t(table[:, 2]), self._edges(table[:, 7])
        counts = table[:, 3:7].astype(np.int32)
        self.samples_delivered += n
        return Batch(self.name, host, t_us * 1e-6, {"data": counts, "seq": seq, "sync_edges": edges})

    # -- health and identity -----------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def stats(self) -> dict[str, Any]:
        """Decoder counters (CRC errors, gaps, lost frames, bytes discarded, ...) and samples delivered."""
        with self._lock:
            d: dict[str, Any] = dict(self.decoder.stats.as_dict())
            queued = len(self._rows)
        d.update(samples_delivered=self.samples_delivered, samples_queued=queued, fault=self._fault)
        return d

    def _check_health(self) -> None:
        """Also: more than ``MAX_LOST_FRACTION`` of the frames expected in a window of ``LOST_WINDOW_FRAMES``
        lost (sequence gaps: another program reading the port, a failing cable) is a fault."""
        super()._check_health()
        with self._lock:
            got, lost = self.counters.received, self.counters.dropped
            got0, lost0 = self._window
            expected, missing = (got - got0) + (lost - lost0), lost - lost0
            if expected < LOST_WINDOW_FRAMES or self.max_lost_fraction is None:
                return
            self._window = (got, lost)
        if missing > self.max_lost_fraction * expected:
            raise DeviceFault(
                f"{self.name}: {missing} of {expected} frames lost ({100 * missing / expected:.1f} % > "
                f"{100 * self.max_lost_fraction:g} %): another program reading {self.port}, or a failing link?"
            )

    def health(self) -> dict[str, Any]:
        """As every stream's, plus the bytes that were no frame (``junk_bytes``; before the first frame only more
        than a port opened mid-frame leaves)."""
        with self._lock:
            st = self.decoder.stats
            junk = (
                st.bytes_discarded + st.unsupported_bytes + (st.startup_bytes if st.startup_bytes >= FRAME_LEN else 0)
            )
        return {**super().health(), "junk_bytes": junk}

    def check(self, silence_s: float | None = None) -> None:
        """Raise :class:`DeviceFault` if the port failed or no frame arrived for ``silence_s`` (default: the
        driver's ``silence_timeout_s``) while running."""
        if silence_s is None:
            super().check()
            return
        keep, self.silence_timeout_s = self.silence_timeout_s, silence_s
        try:
            super().check()
        finally:
            self.silence_timeout_s = keep

    def identity(self) -> dict[str, Any]:
        return {
            "device": "load-cell plate MCU",
            "port": self.port,
            "baudrate": self.baudrate,
            "protocol_version": self.decoder.stats.last_version,
            "driver_protocol_version": VERSION,
            "crc": CRC_NAME,
        }

    def ping(self, duration_s: float = 0.3) -> LoadCellPing:
        """Open the port, listen for ``duration_s``, close it, and say what was found (not while running)."""
        if self.running:
            raise RuntimeError(f"{self.name}: ping() would steal samples from a running stream")
        try:
            self.start()
        except DeviceFault as exc:
            return LoadCellPing(self.port, False, error=str(exc))
        batches = []
        t_end = time.monotonic() + duration_s
        try:
            while time.monotonic() < t_end:
                time.sleep(0.02)
                batches.append(self.read())
        except DeviceFault as exc:
            return LoadCellPing(self.port, False, error=str(exc), stats=self.stats())
        finally:
            self.stop()
        stats = self.stats()
        b = Batch.concat(batches)
        if len(b) == 0:
            unsupported = stats["last_version"] is not None and stats["unsupported"] > 0
            why = (
                f"MCU speaks protocol v{stats['last_version']}, this driver v{VERSION}"
                if unsupported
                else f"no valid frame in {duration_s:g} s ({stats['bytes_in']} bytes received"
                + (": wrong baud rate or not a beambench load-cell MCU?)" if stats["bytes_in"] else ")")
            )
            return LoadCellPing(self.port, False, stats=stats, error=why)
        rate = host_rate = None
        if len(b) > 1:
            span = b.device_time[-1] - b.device_time[0]
            rate = (len(b) - 1) / span if span > 0 else None
            hspan = (b.host_time_ns[-1] - b.host_time_ns[0]) * 1e-9
            host_rate = (len(b) - 1) / hspan if hspan > 0 else None
        return LoadCellPing(self.port, True, len(b), stats["last_version"], rate, host_rate, stats)


def ping(port: str, baudrate: int = DEFAULT_BAUDRATE, duration_s: float = 0.3) -> LoadCellPing:
    """What is on ``port``: protocol version and frame rate of a load-cell MCU (for ``beambench devices``)."""
    return SerialLoadCells(port, baudrate).ping(duration_s)
