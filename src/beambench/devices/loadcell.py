"""Load-cell plate driver: the MCU's serial frames (see :mod:`beambench.devices.loadcell_protocol`) as a Stream.

A reader thread reads the port with pyserial, feeds a :class:`StreamDecoder` and queues the frames, stamped
with ``time.monotonic_ns()`` when their bytes arrived (every frame of one read shares that receive time).
:meth:`SerialLoadCells.read` hands out everything queued as one :class:`~beambench.acquisition.batch.Batch` of
:func:`beambench.acquisition.streams.loadcell_spec`: ``device_time`` is the MCU microsecond clock in seconds, and ``seq`` and
``sync_edges`` are unwrapped from 32 bits, across batches. Bad bytes are counted, never raised; only a port
that fails or disappears raises :class:`~beambench.acquisition.capabilities.DeviceFault` (from ``read`` once the samples
received before the failure are handed out, or from :meth:`check`).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import serial

from beambench.acquisition.batch import Batch, StreamSpec
from beambench.acquisition.capabilities import DeviceFault
from beambench.acquisition.streams import LOADCELL, LOADCELL_RATE_HZ, loadcell_spec
from beambench.devices.loadcell_protocol import CRC_NAME, VERSION, Frame, StreamDecoder

DEFAULT_BAUDRATE = 921_600
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


class SerialLoadCells:
    """The load-cell plate on a serial port (a device path or any pyserial URL, e.g. ``socket://host:port``)."""

    def __init__(
        self,
        port: str,
        baudrate: int = DEFAULT_BAUDRATE,
        *,
        name: str = LOADCELL,
        rate_hz: float = LOADCELL_RATE_HZ,
        read_timeout_s: float = 0.05,
        exclusive: bool = True,
    ) -> None:
        self.name = name
        self.port = port
        self.baudrate = baudrate
        self.rate_hz = rate_hz
        self._timeout = read_timeout_s
        self._exclusive = exclusive
        self._spec = loadcell_spec(rate_hz)
        self._ser: serial.SerialBase | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._reset_state()

    def _reset_state(self) -> None:
        self.decoder = StreamDecoder()
        self._frames: list[Frame] = []
        self._hosts: list[tuple[int, int]] = []  # (receive time ns, frames received at it)
        self._fault: str | None = None
        self._t = Unwrap32()
        self._seq = Unwrap32()
        self._edges = Unwrap32()
        self.samples_delivered = 0
        self.last_frame_ns: int | None = None

    # -- Stream ------------------------------------------------------------------------------------------
    def describe(self) -> StreamSpec:
        return self._spec

    def start(self) -> None:
        """Open the port and start the reader thread. Raises :class:`DeviceFault` if the port cannot open."""
        if self._thread is not None:
            return
        self._reset_state()
        try:
            self._ser = serial.serial_for_url(
                self.port, baudrate=self.baudrate, timeout=self._timeout, exclusive=self._exclusive
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceFault(f"{self.name}: cannot open serial port {self.port}: {exc}") from exc
        self._stop.clear()
        self._thread = threading.Thread(target=self._reader, name=f"{self.name}-reader", daemon=True)
        self._thread.start()

    def read(self) -> Batch:
        """Every sample received since the last call; raises :class:`DeviceFault` once the port has failed."""
        with self._lock:
            frames, self._frames = self._frames, []
            hosts, self._hosts = self._hosts, []
            fault = self._fault
        if not frames:
            if fault is not None:
                raise DeviceFault(f"{self.name}: serial port {self.port} failed: {fault}")
            return self._spec.empty_batch()
        host = np.repeat(np.array([h for h, _ in hosts], np.int64), [k for _, k in hosts])
        t_us = self._t(np.fromiter((f.t_us for f in frames), np.int64, len(frames)))
        seq = self._seq(np.fromiter((f.seq for f in frames), np.int64, len(frames)))
        edges = self._edges(np.fromiter((f.sync_edges for f in frames), np.int64, len(frames)))
        counts = np.array([f.counts for f in frames], dtype=np.int32).reshape(-1, 4)
        self.samples_delivered += len(frames)
        return Batch(self.name, host, t_us * 1e-6, {"data": counts, "seq": seq, "sync_edges": edges})

    def stop(self) -> None:
        """Stop the reader and close the port. Idempotent."""
        self._stop.set()
        ser = self._ser
        if ser is not None and hasattr(ser, "cancel_read"):
            try:
                ser.cancel_read()
            except Exception:
                pass
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if ser is not None:
            try:
                ser.close()
            except Exception:
                pass
            self._ser = None

    def __enter__(self) -> SerialLoadCells:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- health and identity -----------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def stats(self) -> dict[str, Any]:
        """Decoder counters (CRC errors, gaps, lost frames, bytes discarded, ...) and samples delivered."""
        with self._lock:
            d = self.decoder.stats.as_dict()
            queued = len(self._frames)
        d.update(samples_delivered=self.samples_delivered, samples_queued=queued, fault=self._fault)
        return d

    def check(self, silence_s: float = 0.5) -> None:
        """Raise :class:`DeviceFault` if the port failed or no frame arrived for ``silence_s`` while running."""
        if self._fault is not None:
            raise DeviceFault(f"{self.name}: serial port {self.port} failed: {self._fault}")
        last = self.last_frame_ns
        if self.running and last is not None and time.monotonic_ns() - last > silence_s * 1e9:
            raise DeviceFault(f"{self.name}: no frame from {self.port} for more than {silence_s:g} s")

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

    # -- reader thread -----------------------------------------------------------------------------------
    def _reader(self) -> None:
        ser = self._ser
        assert ser is not None
        dec = self.decoder
        try:
            while not self._stop.is_set():
                data = ser.read(max(1, ser.in_waiting))
                if not data:
                    continue
                now = time.monotonic_ns()
                with self._lock:
                    frames = dec.feed(data)
                    if frames:
                        self._frames.extend(frames)
                        self._hosts.append((now, len(frames)))
                        self.last_frame_ns = now
        except Exception as exc:  # port unplugged, pty closed, ...: reported by read()/check()
            if not self._stop.is_set():
                with self._lock:
                    self._fault = f"{type(exc).__name__}: {exc}"


def ping(port: str, baudrate: int = DEFAULT_BAUDRATE, duration_s: float = 0.3) -> LoadCellPing:
    """What is on ``port``: protocol version and frame rate of a load-cell MCU (for ``beambench devices``)."""
    return SerialLoadCells(port, baudrate).ping(duration_s)
