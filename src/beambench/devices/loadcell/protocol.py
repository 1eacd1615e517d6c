"""Wire format of the load-cell plate's microcontroller link, and its incremental decoder.

The MCU samples four load cells at 1 kHz and sends one frame per sample over a serial port (UART or USB CDC).
All multi-byte fields are little-endian. Version 1 frame, 34 bytes::

    offset size field       type    meaning
    0      2    sync        -       0xA5 0x5A
    2      1    length      u8      bytes from ``version`` to the last payload byte (29 in version 1)
    3      1    version     u8      protocol version (1)
    4      4    seq         u32     frame sequence number, +1 per frame, wraps at 2**32
    8      4    t_us        u32     MCU microsecond clock at the sample, wraps at 2**32 (71.6 min)
    12     16   counts      4×i32   raw ADC counts of channels 0..3
    28     4    sync_edges  u32     rising edges counted on the mocap exposure (sync) input, wraps at 2**32
    32     2    crc         u16     CRC-16/CCITT-FALSE over bytes 2..31 (length .. sync_edges)

CRC-16/CCITT-FALSE (also catalogued as CRC-16/IBM-3740): polynomial 0x1021, initial value 0xFFFF, no input or
output reflection, no final XOR; check value 0x29B1 for ``b"123456789"``. It is :func:`binascii.crc_hqx` with
initial value 0xFFFF. The CRC covers the length byte, so a corrupted length is detected too. At 1 kHz the link
carries 34 000 B/s: 340 kbit/s with 8N1 framing, so a UART needs at least 460 800 baud (921 600 recommended).

Decoding rules (:class:`StreamDecoder`):

- A *candidate* starts at every ``A5 5A`` with a non-zero length byte; it is complete once ``length + 5`` bytes
  are buffered. A complete candidate whose CRC matches is a frame: version 1 with length 29 is decoded, any
  other (version, length) is counted as ``unsupported`` and skipped whole. An incomplete candidate of another
  version is dropped as soon as a complete valid frame starts inside its span, so a false sync with a long
  length never holds valid frames back.
- A version-1 candidate whose CRC fails is either *truncated* (bytes were lost: a valid frame starts inside
  its span, which is then decoded) or a *CRC error* (bytes were corrupted). Either way the decoder advances by
  a single byte, so no valid frame hidden behind a false sync is ever lost.
- Bytes outside valid frames are counted as discarded. Before the first valid frame (the decoder has not yet
  locked onto the stream, e.g. a port opened mid-frame) they are counted as ``startup_bytes`` and no errors
  are counted. Each stretch of discarded bytes between two valid frames (a corrupted or truncated frame, noise
  on the line, bytes another program wrote) counts one ``junk_runs``; so does a start before the first frame
  longer than one frame (more than a port opened mid-frame explains).
- Sequence numbers: a forward jump counts one gap and ``jump - 1`` lost frames; a backward step (MCU reset,
  duplicate) counts a ``seq_reset``.

:meth:`StreamDecoder.feed` never raises on any input and never waits: it decodes what is buffered and keeps
an incomplete tail (at most one candidate, < 520 bytes). :func:`decode_frame` decodes exactly one frame and
raises :class:`LoadCellParseError` on anything else. Documented in ``docs/loadcell-protocol.md``.
"""

from __future__ import annotations

import binascii
import struct
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import NamedTuple

from beambench.common.errors import BeambenchError

SYNC = b"\xa5\x5a"
VERSION = 1
PAYLOAD_LEN = 29  # version .. sync_edges
FRAME_LEN = 2 + 1 + PAYLOAD_LEN + 2  # 34
CRC_NAME = "CRC-16/CCITT-FALSE"
CRC_INIT = 0xFFFF

_FRAME = struct.Struct("<2sBBIIiiiiIH")  # the whole version-1 frame
_BODY = struct.Struct("<BBIIiiiiI")  # length .. sync_edges (the CRC-covered bytes)
_CRC = struct.Struct("<H")
_KNOWN = {(VERSION, PAYLOAD_LEN)}
_U32 = 1 << 32
_SYNC0 = SYNC[0]


class LoadCellParseError(BeambenchError, ValueError):
    """A byte string is not exactly one valid load-cell frame (raised only by :func:`decode_frame`)."""


class Frame(NamedTuple):
    """One decoded sample."""

    version: int
    seq: int
    t_us: int
    counts: tuple[int, int, int, int]
    sync_edges: int


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE of ``data``."""
    return binascii.crc_hqx(data, CRC_INIT)


def encode_frame(seq: int, t_us: int, counts: Sequence[int], sync_edges: int = 0) -> bytes:
    """The 34-byte version-1 frame; ``seq``, ``t_us`` and ``sync_edges`` are taken modulo 2**32."""
    c0, c1, c2, c3 = (int(c) for c in counts)
    body = _BODY.pack(PAYLOAD_LEN, VERSION, seq % _U32, t_us % _U32, c0, c1, c2, c3, sync_edges % _U32)
    return SYNC + body + _CRC.pack(crc16(body))


def decode_frame(data: bytes | bytearray | memoryview) -> Frame:
    """Decode exactly one frame; raise :class:`LoadCellParseError` saying what is wrong otherwise."""
    data = bytes(data)
    if len(data) < 4:
        raise LoadCellParseError(f"frame too short: {len(data)} bytes, need {FRAME_LEN}")
    if data[:2] != SYNC:
        raise LoadCellParseError(f"bad sync bytes {data[:2].hex()}, expected {SYNC.hex()}")
    length, version = data[2], data[3]
    if len(data) != length + 5:
        raise LoadCellParseError(f"frame is {len(data)} bytes but its length byte says {length + 5}")
    (crc,) = _CRC.unpack_from(data, len(data) - 2)
    if crc16(data[2:-2]) != crc:
        raise LoadCellParseError(f"{CRC_NAME} mismatch: frame says {crc:#06x}, computed {crc16(data[2:-2]):#06x}")
    if (version, length) not in _KNOWN:
        raise LoadCellParseError(f"unsupported frame version {version} (length {length}); this driver speaks {VERSION}")
    _, _, _, seq, t_us, c0, c1, c2, c3, edges, _ = _FRAME.unpack(data)
    return Frame(version, seq, t_us, (c0, c1, c2, c3), edges)


@dataclass
class DecoderStats:
    """Counters of a :class:`StreamDecoder` (bytes add up: ``bytes_in == 34·frames + unsupported_bytes +
    bytes_discarded + startup_bytes + pending``)."""

    bytes_in: int = 0
    frames: int = 0
    crc_errors: int = 0
    truncated: int = 0
    unsupported: int = 0
    unsupported_bytes: int = 0
    seq_gaps: int = 0
    lost_frames: int = 0
    seq_resets: int = 0
    bytes_discarded: int = 0
    startup_bytes: int = 0
    junk_runs: int = 0  # stretches of bytes that were no frame (see the module docstring)
    last_version: int | None = None

    def as_dict(self) -> dict[str, int | None]:
        return asdict(self)


class StreamDecoder:
    """Incremental, resynchronising decoder: :meth:`feed` bytes as they arrive, get whole frames back."""

    def __init__(self) -> None:
        self.stats = DecoderStats()
        self._buf = bytearray()
        self._last_seq: int | None = None
        self._in_junk = False  # the last bytes consumed were discarded (a junk run is open)

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a candidate frame."""
        return len(self._buf)

    @property
    def locked(self) -> bool:
        """True once a valid frame has been seen (errors are counted from then on)."""
        return self._last_seq is not None

    def reset(self) -> None:
        self.stats = DecoderStats()
        self._buf = bytearray()
        self._last_seq = None
        self._in_junk = False

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Append ``data`` and return every frame completed by it, in order. Never raises, never waits."""
        buf = self._buf
        buf += data
        st = self.stats
        st.bytes_in += len(data)
        out: list[Frame] = []
        pos = 0
        n = len(buf)
        while True:
            i = buf.find(SYNC, pos)
            if i < 0:
                end = n - 1 if n > pos and buf[n - 1] == _SYNC0 else n  # keep a trailing A5
                self._discard(end - pos)
                pos = end
                break
            if i > pos:
                self._discard(i - pos)
                pos = i
            if n - i < 4:
                break
            length = buf[i + 2]
            if length == 0:
                self._discard(1)
                pos = i + 1
                continue
            total = length + 5
            known = length == PAYLOAD_LEN and buf[i + 3] == VERSION
            if n - i < total:
                if known or not self._frame_inside(buf, i, i + total):
                    break  # wait for the rest of the candidate
                self._discard(1)  # a false sync: a complete valid frame starts inside its span
                pos = i + 1
                continue
            if crc16(buf[i + 2 : i + total - 2]) == buf[i + total - 2] | (buf[i + total - 1] << 8):
                if known:
                    out.append(self._accept(buf, i))
                else:
                    st.unsupported += 1
                    st.unsupported_bytes += total
                    st.last_version = buf[i + 3]
                pos = i + total
                continue
            if known and self.locked:
                j = self._resync_inside(buf, i)
                if j is None:
                    break  # wait for the bytes that tell truncation from corruption
                if j > 0:
                    st.truncated += 1
                    self._discard(j - i)
                    pos = j
                    continue
                st.crc_errors += 1
            self._discard(1)
            pos = i + 1
        if pos:
            del buf[:pos]
        return out

    def _accept(self, buf: bytearray, i: int) -> Frame:
        _, _, version, seq, t_us, c0, c1, c2, c3, edges, _ = _FRAME.unpack_from(buf, i)
        st = self.stats
        st.frames += 1
        st.last_version = version
        self._in_junk = False
        last = self._last_seq
        if last is not None:
            jump = (seq - last) % _U32
            if jump != 1:
                if 0 < jump < _U32 // 2:
                    st.seq_gaps += 1
                    st.lost_frames += jump - 1
                else:
                    st.seq_resets += 1
        self._last_seq = seq
        return Frame(version, seq, t_us, (c0, c1, c2, c3), edges)

    @staticmethod
    def _valid_at(buf: bytearray, j: int) -> bool:
        return (
            buf[j + 2] == PAYLOAD_LEN
            and buf[j + 3] == VERSION
            and crc16(buf[j + 2 : j + FRAME_LEN - 2]) == buf[j + FRAME_LEN - 2] | (buf[j + FRAME_LEN - 1] << 8)
        )

    def _frame_inside(self, buf: bytearray, i: int, end: int) -> bool:
        """Whether a complete valid frame starts inside ``(i, end)`` (so the candidate at ``i`` is false)."""
        j = buf.find(SYNC, i + 1, end + 1)
        while 0 <= j < end and len(buf) - j >= FRAME_LEN:
            if self._valid_at(buf, j):
                return True
            j = buf.find(SYNC, j + 1, end + 1)
        return False

    def _resync_inside(self, buf: bytearray, i: int) -> int | None:
        """Start of a valid frame inside the failed candidate at ``i`` (truncation), -1 if none, None to wait."""
        end = i + FRAME_LEN + 1  # a frame shortened by k >= 1 bytes is followed by a sync at <= i + 33
        j = buf.find(SYNC, i + 1, end)
        while 0 <= j < i + FRAME_LEN:
            if len(buf) - j < FRAME_LEN:
                return None
            if self._valid_at(buf, j):
                return j
            j = buf.find(SYNC, j + 1, end)
        return None if len(buf) < end else -1  # a sync may straddle the end of what has arrived

    def _discard(self, k: int) -> None:
        if k <= 0:
            return
        st = self.stats
        if self.locked:
            st.bytes_discarded += k
            if not self._in_junk:
                st.junk_runs += 1
                self._in_junk = True
        else:
            if st.startup_bytes < FRAME_LEN <= st.startup_bytes + k:
                st.junk_runs += 1  # more than a port opened mid-frame leaves: junk before the first frame
            st.startup_bytes += k
