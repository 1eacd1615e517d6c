"""Emulated load-cell MCU: writes protocol frames at 1 kHz to a pseudo-terminal, like the real board on USB.

``os.openpty()`` gives a master/slave pair; a thread writes frames to the master and the driver opens the slave
path (:attr:`EmulatedLoadCellMCU.port`) with pyserial, exactly as it opens ``/dev/ttyACM0`` on the rig.

- Force: a callable ``force(t) -> (Fn, Ft)`` in newtons, ``t`` in seconds of true (host) time since
  :meth:`start` (frame 0 is sampled at ``time.monotonic_ns() == started_ns``), called from the emulator's
  thread, a few frames at a time; converted to counts with :meth:`LoadCellCalibration.counts_from_force` (the plate's "true"
  calibration), plus optional Gaussian noise, rounded and clipped to int32. Drive it from a physics model by
  passing a callable that reads the simulation's contact force.
- Clock: the MCU samples every ``1e6 / rate_hz`` µs of *its own* clock, which runs ``drift_ppm`` fast, so on
  the host frames arrive at ``rate_hz · (1 + drift_ppm·1e-6)`` per second while ``t_us`` steps by exactly
  1000 µs. ``clock_start_us`` presets the 32-bit clock (e.g. just before its wraparound).
- Sync input: ``sync_edges`` counts mocap exposure pulses at ``sync_rate_hz`` (true time).
- Faults, drawn per frame from a seeded RNG and counted exactly in :attr:`injected`: ``crc_error_prob``
  (one bit flipped after the header), ``drop_prob`` (1–``max_drop`` contiguous bytes removed after the header),
  ``garbage_prob`` (1–``max_garbage`` random bytes before the frame). A faulted frame is followed by one clean
  frame with no garbage before it, so every fault is separately visible to the decoder.
- Like a UART/USB transmit buffer, at most ``tx_buffer`` bytes wait for the host; frames that do not fit are
  not sent (counted as ``frames_overflowed``; the sequence number still advances).
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import fcntl
import math
import os
import random
import struct
import termios
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from beambench.acquisition.clocks import DriftingClock
from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration, default_calibration
from beambench.acquisition.streams import LOADCELL
from beambench.devices.loadcell.protocol import FRAME_LEN, encode_frame
from beambench.devices.peer import PeerContext, Wiring

ForceSource = Callable[[float], tuple[float, float]]
_I32 = (-(2**31), 2**31 - 1)
_HEADER = 4  # sync, length, version: faults are injected after it


def zero_force(t: float) -> tuple[float, float]:
    return (0.0, 0.0)


@dataclass
class Injected:
    """Exact counts of what the emulator sent and broke."""

    frames: int = 0  # frames generated (sent or not)
    crc_errors: int = 0
    frames_truncated: int = 0
    bytes_dropped: int = 0
    garbage_bursts: int = 0
    garbage_bytes: int = 0
    frames_overflowed: int = 0
    bytes_written: int = 0

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


@dataclass(frozen=True)
class McuClock:
    """The MCU's frame clock: nominal rate, drift, where its microsecond clock and sequence number start, and
    the rate of the mocap sync pulses it counts."""

    rate_hz: float = 1000.0
    drift_ppm: float = 0.0
    clock_start_us: int = 0
    seq_start: int = 0
    sync_rate_hz: float = 360.0


@dataclass(frozen=True)
class LinkFaults:
    """Faults injected on the serial link, per frame: CRC errors, dropped bytes (up to ``max_drop``), bursts of
    garbage before a frame (up to ``max_garbage`` bytes)."""

    crc_error_prob: float = 0.0
    drop_prob: float = 0.0
    max_drop: int = 3
    garbage_prob: float = 0.0
    max_garbage: int = 40


class EmulatedLoadCellMCU:
    """The load-cell MCU on a pty. Use as a context manager, or :meth:`open`, :meth:`start`, :meth:`close`."""

    def __init__(
        self,
        force: ForceSource | None = None,
        calibration: LoadCellCalibration | None = None,
        *,
        clock: McuClock = McuClock(),
        faults: LinkFaults = LinkFaults(),
        noise_counts: float = 0.0,
        tx_buffer: int = 8192,
        seed: int = 0,
    ) -> None:
        self.force: ForceSource = force or zero_force
        self.calibration = calibration or default_calibration()
        self.rate_hz = clock.rate_hz
        self.drift_ppm = clock.drift_ppm
        self.clock_start_us = clock.clock_start_us
        self.seq_start = clock.seq_start
        self.sync_rate_hz = clock.sync_rate_hz
        self.noise_counts = noise_counts
        self.crc_error_prob = faults.crc_error_prob
        self.drop_prob = faults.drop_prob
        self.max_drop = max(1, min(faults.max_drop, FRAME_LEN - _HEADER - 1))
        self.garbage_prob = faults.garbage_prob
        self.max_garbage = max(1, faults.max_garbage)
        self.tx_buffer = tx_buffer
        self.injected = Injected()
        self.broken_seqs: list[int] = []  # sequence numbers of frames sent with a CRC error or bytes dropped
        self.overflowed_seqs: list[int] = []  # sequence numbers never sent (transmit buffer full)
        self._rng = random.Random(seed)
        self._noise = np.random.default_rng(seed)
        # a fault is always followed by a clean frame (the driver sees a fault by the frame after it); the board's
        # first frame is clean too (a driver that opens the port first reads it whole)
        self._guard = True
        self._k = 0
        self._master: int | None = None
        self._slave: int | None = None
        self.port: str | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._tx = bytearray()
        self.error: str | None = None
        self.started_ns: int | None = None  # host monotonic time of frame 0

    # -- frames ------------------------------------------------------------------------------------------
    @property
    def true_rate_hz(self) -> float:
        """Frames per second of host (true) time: the nominal rate on a clock running ``drift_ppm`` fast."""
        return DriftingClock(drift_ppm=self.drift_ppm).rate_on_host(self.rate_hz)

    def set_force(self, force: ForceSource) -> None:
        self.force = force

    def switch_force(self, force: tuple[float, float]) -> int:
        """The plate carries ``force`` from now on, by the frames' own sample times (frames made late, after a
        starved thread wakes, still carry the force of their time); returns the first such frame's sequence
        number."""
        if self.started_ns is None:
            self.force = lambda t: force
            return self.seq_start
        rate = self.true_rate_hz
        k = math.ceil((time.monotonic_ns() - self.started_ns) * 1e-9 * rate)
        before = self.force
        self.force = lambda t: force if round(t * rate) >= k else before(t)
        return self.seq_start + k

    def counts_at(self, t: float) -> np.ndarray:
        """Noise-free counts (float) for the force at true time ``t``."""
        return self.calibration.counts_from_force(np.asarray(self.force(t), dtype=float))

    def frames_bytes(self, k0: int, n: int) -> list[bytes]:
        """Frames ``k0 .. k0+n-1`` (numbered from :meth:`start`) as sent: faults and preceding garbage included."""
        if n <= 0:
            return []
        ks = np.arange(k0, k0 + n)
        ts = ks / self.true_rate_hz
        forces = np.array([self.force(float(t)) for t in ts], dtype=float).reshape(n, 2)
        counts = self.calibration.counts_from_force(forces)
        if self.noise_counts:
            counts = counts + self._noise.normal(0.0, self.noise_counts, (n, 4))
        counts = np.clip(np.rint(counts), *_I32).astype(np.int64).tolist()
        t_us = (self.clock_start_us + np.rint(ks * (1e6 / self.rate_hz))).astype(np.int64).tolist()
        edges = np.floor(ts * self.sync_rate_hz).astype(np.int64).tolist() if self.sync_rate_hz else [0] * n
        rows = zip(ks.tolist(), t_us, counts, edges)
        return [self._faults(encode_frame(self.seq_start + k, t, c, e), self.seq_start + k) for k, t, c, e in rows]

    def _faults(self, frame: bytes, seq: int = -1) -> bytes:
        """Apply this frame's drawn faults (and garbage before it), counting them in :attr:`injected`."""
        self.injected.frames += 1
        if self._guard:
            self._guard = False
            return frame
        rng, inj = self._rng, self.injected
        garbage = b""
        if self.garbage_prob and rng.random() < self.garbage_prob:
            garbage = rng.randbytes(rng.randint(1, self.max_garbage))
            inj.garbage_bursts += 1
            inj.garbage_bytes += len(garbage)
        u = rng.random()
        if u < self.crc_error_prob:
            b = bytearray(frame)
            b[rng.randrange(_HEADER, FRAME_LEN)] ^= 1 << rng.randrange(8)
            frame = bytes(b)
            inj.crc_errors += 1
            self.broken_seqs.append(seq)
            self._guard = True
        elif u < self.crc_error_prob + self.drop_prob:
            n = rng.randint(1, self.max_drop)
            at = rng.randrange(_HEADER, FRAME_LEN - n + 1)
            frame = frame[:at] + frame[at + n :]
            inj.frames_truncated += 1
            inj.bytes_dropped += n
            self.broken_seqs.append(seq)
            self._guard = True
        return garbage + frame

    def render(self, n: int) -> bytes:
        """The next ``n`` frames as one byte string (no pty, no timing): for tests and benchmarks."""
        out = b"".join(self.frames_bytes(self._k, n))
        self._k += n
        return out

    # -- pty and thread ----------------------------------------------------------------------------------
    def open(self) -> str:
        """Create the pseudo-terminal (raw mode) and return the path the driver should open."""
        if self.port is None:
            self._master, self._slave = os.openpty()
            tty.setraw(self._slave)  # no echo, no newline translation: a clean 8-bit line
            os.set_blocking(self._master, False)
            self.port = os.ttyname(self._slave)
        return self.port

    def start(self) -> None:
        """Start sending frames (opens the pty if needed); frame 0 is sampled now."""
        self.open()
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="loadcell-mcu", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop sending (the pty stays open, so the driver can still read what was sent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def close(self) -> None:
        """Stop and close the pty (a driver still reading it sees the port disappear). Idempotent."""
        self.stop()
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None

    def __enter__(self) -> EmulatedLoadCellMCU:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def flushed(self) -> bool:
        """True when everything generated has been handed to the pty."""
        return not self._tx

    def unread(self) -> int:
        """Bytes on the line that no reader has taken yet (the pty's input queue, as ``FIONREAD`` counts it)."""
        if self._slave is None:
            return 0
        return int(struct.unpack("i", fcntl.ioctl(self._slave, termios.FIONREAD, b"\0" * 4))[0])

    def _run(self) -> None:
        self.started_ns = time.monotonic_ns()
        t0 = self.started_ns * 1e-9
        k0 = self._k
        rate = self.true_rate_hz
        try:
            while not self._stop.is_set():
                due = k0 + int((time.monotonic() - t0) * rate) + 1
                if due > self._k:
                    before = dataclasses.replace(self.injected)
                    n_broken = len(self.broken_seqs)
                    frames = self.frames_bytes(self._k, due - self._k)
                    self._k = due
                    if len(self._tx) + sum(map(len, frames)) > self.tx_buffer:  # not sent: no fault happened
                        before.frames = self.injected.frames
                        before.frames_overflowed += len(frames)
                        self.injected = before
                        del self.broken_seqs[n_broken:]
                        self.overflowed_seqs.extend(range(self.seq_start + due - len(frames), self.seq_start + due))
                    else:
                        self._tx += b"".join(frames)
                self._write()
                self._drain_input()
                time.sleep(0.001)
            if self._guard and self._k:  # the last frame was broken: end on the clean one that shows it
                self._tx += b"".join(self.frames_bytes(self._k, 1))
                self._k += 1
            deadline = time.monotonic() + 1.0
            while self._tx and time.monotonic() < deadline:  # flush the transmit buffer
                self._write()
                time.sleep(0.001)
        except Exception as exc:  # a bad force callable must not die silently
            self.error = f"{type(exc).__name__}: {exc}"

    def _write(self) -> None:
        if not self._tx or self._master is None:
            return
        try:
            n = os.write(self._master, self._tx)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EIO):
                return
            raise
        del self._tx[:n]
        self.injected.bytes_written += n

    def _drain_input(self) -> None:
        """Discard anything the host wrote (the protocol is one-way), so the pty never fills up."""
        try:
            while os.read(self._master, 4096):  # type: ignore[arg-type]
                pass
        except OSError:
            pass


class LoadCellPeer:
    """The ``loadcells`` stream's emulated peer: the load-cell MCU on a pseudo-terminal, sending the physics' plate
    force through the calibration, on its own drifting clock (``sim.clocks.loadcell``). Injections: ``loadcell_crc``,
    ``loadcell_drop``, ``loadcell_garbage`` (probabilities per frame) and ``loadcell_stop_s`` (the board stops
    sending this many seconds after it started)."""

    def __init__(self, ctx: PeerContext) -> None:
        inject = ctx.inject
        self.mcu = EmulatedLoadCellMCU(
            force=ctx.physics.force,
            calibration=ctx.calibration,
            clock=McuClock(drift_ppm=ctx.clock(LOADCELL).drift_ppm),
            noise_counts=50.0 if ctx.noise else 0.0,
            seed=ctx.seed,
            faults=LinkFaults(
                crc_error_prob=inject.get("loadcell_crc", 0.0),
                drop_prob=inject.get("loadcell_drop", 0.0),
                garbage_prob=inject.get("loadcell_garbage", 0.0),
            ),
            tx_buffer=1 << 22,  # frames the emulator sends late when its own process was starved are not lost
        )
        self._stop_s: Any = inject.get("loadcell_stop_s")
        self._stopper: threading.Timer | None = None

    def open(self) -> Wiring:
        return {"loadcell": {"port": self.mcu.open()}}

    def start(self) -> None:
        self.mcu.start()
        if self._stop_s is not None:
            self._stopper = threading.Timer(float(self._stop_s), self.mcu.stop)
            self._stopper.daemon = True
            self._stopper.start()

    def stop(self) -> None:
        if self._stopper is not None:
            self._stopper.cancel()
        self.mcu.stop()

    def report(self) -> dict[str, Any]:
        m = self.mcu
        return {
            "injected": m.injected.as_dict(),
            "broken_seqs": list(m.broken_seqs),
            "overflowed_seqs": list(m.overflowed_seqs),
            "error": m.error or "",
        }

    def close(self) -> None:
        self.mcu.close()
