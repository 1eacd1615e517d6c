"""The NatNet codec's ground floor: message ids, versions, the errors, the struct layouts and the bounds-checked
reader every message parses with (shared by :mod:`.protocol`, :mod:`.modeldef` and :mod:`.frame`; the package's
face is :mod:`.protocol`)."""

from __future__ import annotations

import struct
from enum import IntEnum
from typing import NamedTuple

from beambench.common.errors import BeambenchError

MAX_NAME = 256
MAX_PAYLOAD = 65535


class NatNetParseError(BeambenchError, ValueError):
    """A packet is malformed, truncated or of an unsupported version."""


class MessageId(IntEnum):
    CONNECT = 0
    SERVERINFO = 1
    REQUEST = 2
    RESPONSE = 3
    REQUEST_MODELDEF = 4
    MODELDEF = 5
    REQUEST_FRAMEOFDATA = 6
    FRAMEOFDATA = 7
    MESSAGESTRING = 8
    DISCONNECT = 9
    KEEPALIVE = 10
    DISCONNECTBYTIMEOUT = 11
    ECHOREQUEST = 12
    ECHORESPONSE = 13
    DISCOVERY = 14
    UNRECOGNIZED_REQUEST = 100


class Version(NamedTuple):
    """A NatNet or application version ``major.minor.build.revision``; compares as a tuple."""

    major: int
    minor: int = 0
    build: int = 0
    revision: int = 0

    @classmethod
    def parse(cls, text: str) -> Version:
        """``"4.1"`` or ``"4.1.0.0"`` → Version; ValueError on anything else."""
        parts = [int(p) for p in str(text).strip().split(".")]
        if not 1 <= len(parts) <= 4 or any(not 0 <= p <= 255 for p in parts):
            raise ValueError(f"not a version: {text!r}")
        return cls(*parts)

    def short(self) -> str:
        return f"{self.major}.{self.minor}"

    def __str__(self) -> str:
        return ".".join(str(p) for p in self)


_V0 = Version(0)


V3_0, V4_0, V4_1 = Version(3, 0), Version(4, 0), Version(4, 1)
SUPPORTED_VERSIONS = (V3_0, V4_0, V4_1)

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]

_U8x4 = struct.Struct("<4B")
_I16 = struct.Struct("<h")
_I32 = struct.Struct("<i")
_I32_UNPACK = _I32.unpack_from
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_F32 = struct.Struct("<f")
_F64 = struct.Struct("<d")
_V3 = struct.Struct("<3f")
_V4 = struct.Struct("<4f")
_HEADER = struct.Struct("<HH")
_RB = struct.Struct("<i3f4ffh")  # id, position, orientation, mean error, params (NatNet >= 3.0)
_LM = struct.Struct("<i3ffhf")  # id, position, size, params, residual (NatNet >= 3.0)
_ASSET_RB = _RB
_ASSET_MK = struct.Struct("<i3ffhf")  # id, position, size, params, residual
_SUFFIX_TIMES = struct.Struct("<IIdQQQ")  # timecode, subframe, timestamp, mid-exposure, data received, transmit
_PRECISION = struct.Struct("<II")
_SERVER_TAIL = struct.Struct("<QH?4B")  # clock frequency, data port, multicast, group address


# --------------------------------------------------------------------------------------------- reading


class _Reader:
    """Bounds-checked little-endian reader over one payload; every failure is a NatNetParseError."""

    __slots__ = ("data", "end", "pos")

    def __init__(self, data: bytes, pos: int = 0, end: int | None = None) -> None:
        self.data = data
        self.pos = pos
        self.end = len(data) if end is None else end

    def remaining(self) -> int:
        return self.end - self.pos

    def need(self, n: int, what: str) -> None:
        if n < 0 or self.pos + n > self.end:
            raise NatNetParseError(f"truncated {what}: need {n} bytes at offset {self.pos}, have {self.end - self.pos}")

    # unpack, i32 and count run ~40 times a frame at 360 Hz: the bounds check is inlined rather than a call
    def unpack(self, st: struct.Struct, what: str) -> tuple:
        pos, size = self.pos, st.size
        if pos + size > self.end:
            self.need(size, what)  # raises, with the message
        self.pos = pos + size
        return st.unpack_from(self.data, pos)

    def i32(self, what: str) -> int:
        pos = self.pos
        if pos + 4 > self.end:
            self.need(4, what)
        self.pos = pos + 4
        return _I32_UNPACK(self.data, pos)[0]

    def count(self, what: str, min_item_size: int) -> int:
        """A non-negative int32 item count that can fit in what is left (guards against absurd counts)."""
        pos = self.pos
        if pos + 4 > self.end:
            self.need(4, what)
        n: int = _I32_UNPACK(self.data, pos)[0]
        self.pos = pos = pos + 4
        if n < 0 or n * (min_item_size if min_item_size > 1 else 1) > self.end - pos:
            raise NatNetParseError(f"bad {what} {n} at offset {pos - 4} ({self.end - pos} bytes left)")
        return n

    def cstring(self, what: str) -> str:
        i = self.data.find(b"\0", self.pos, self.end)
        if i < 0:
            raise NatNetParseError(f"unterminated {what} at offset {self.pos}")
        s = bytes(self.data[self.pos : i]).decode("utf-8", errors="replace")
        self.pos = i + 1
        return s

    def fixed_string(self, size: int, what: str) -> str:
        self.need(size, what)
        raw = bytes(self.data[self.pos : self.pos + size])
        self.pos += size
        return raw.split(b"\0", 1)[0].decode("utf-8", errors="replace")

    def rest(self) -> bytes:
        out = bytes(self.data[self.pos : self.end])
        self.pos = self.end
        return out


def _cstr(s: str) -> bytes:
    b = s.encode("utf-8")
    if b"\0" in b:
        raise ValueError(f"string contains NUL: {s!r}")
    return b + b"\0"


def _fixed(s: str, size: int = MAX_NAME) -> bytes:
    b = s.encode("utf-8")[: size - 1]
    return b + b"\0" * (size - len(b))


def _check_version(version: Version | None) -> Version:
    if version is None:
        raise NatNetParseError("the NatNet version is needed to decode this message (no SERVERINFO seen yet)")
    v = Version(*version)
    if v.major not in (3, 4):
        raise NatNetParseError(f"unsupported NatNet version {v} (supported: 3.0, 4.0, 4.1)")
    return v


def _has_sizes(v: Version) -> bool:
    return v >= V4_1
