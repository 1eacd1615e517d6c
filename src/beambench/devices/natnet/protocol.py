"""NatNet (OptiTrack Motive) wire format, versions 3.0, 4.0 and 4.1: a pure codec, no sockets.

Every UDP payload is one packet: ``uint16 message id, uint16 payload bytes, payload``; all integers and floats
little-endian, strings NUL-terminated (fixed 256 bytes in the sender block). Written from the NatNet SDK's
packet description (``NatNetTypes.h``, PacketClient and the SDK's Python sample); verified against a real
Motive 2.1 capture in the tests. What each version adds to a frame of data:

- 3.0: rigid bodies lose their per-body marker lists; labeled markers gain a residual; the frame suffix gains
  the camera mid-exposure, camera-data-received and transmit timestamps (host QPC ticks; the tick rate is
  the ``clock_frequency`` of SERVERINFO).
- 4.0: rigid-body descriptions in MODELDEF carry marker names.
- 4.1: every section of a frame and every MODELDEF entry is preceded by its size in bytes; frames gain an
  assets section and the precision (PTP) timestamp (seconds, fractional seconds) before the frame params.

Any malformed or truncated packet raises :class:`NatNetParseError` and nothing else. Entry points:
:func:`decode` (packet → message object) and :func:`encode` (message → packet).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any, ClassVar, NamedTuple

from beambench.common.errors import BeambenchError

__all__ = [
    "Connect",
    "Disconnect",
    "DisconnectByTimeout",
    "Discovery",
    "EchoRequest",
    "EchoResponse",
    "FrameOfData",
    "KeepAlive",
    "LabeledMarker",
    "MessageId",
    "MessageString",
    "ModelDef",
    "NatNetParseError",
    "Request",
    "RequestFrameOfData",
    "RequestModelDef",
    "Response",
    "RigidBody",
    "Sender",
    "ServerInfo",
    "UnrecognizedRequest",
    "Version",
    "decode",
    "encode",
    "peek_message_id",
]

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


# --------------------------------------------------------------------------------------------- simple messages


@dataclass(frozen=True)
class Sender:
    """The 264-byte sender block: application name, application version, NatNet version."""

    name: str
    version: Version = _V0
    natnet_version: Version = _V0

    SIZE: ClassVar[int] = MAX_NAME + 8

    def pack(self) -> bytes:
        return _fixed(self.name) + _U8x4.pack(*self.version) + _U8x4.pack(*self.natnet_version)

    @classmethod
    def read(cls, r: _Reader) -> Sender:
        name = r.fixed_string(MAX_NAME, "sender name")
        app = Version(*r.unpack(_U8x4, "sender version"))
        nn = Version(*r.unpack(_U8x4, "sender NatNet version"))
        return cls(name, app, nn)


@dataclass(frozen=True)
class Connect:
    """Client → server on the command port: who I am, and optionally which bitstream version I want."""

    sender: Sender
    subscribed_data_only: bool = False
    bitstream_version: Version | None = None

    ID: ClassVar[int] = MessageId.CONNECT

    def payload(self, version: Version | None = None) -> bytes:
        out = self.sender.pack()
        if self.bitstream_version is not None or self.subscribed_data_only:
            bv = self.bitstream_version or Version(0)
            out += bytes([1 if self.subscribed_data_only else 0]) + _U8x4.pack(*bv)
        return out

    @classmethod
    def parse(cls, r: _Reader, version: Version | None) -> Connect:
        if r.remaining() < Sender.SIZE:  # some clients send just "Ping\0"; Motive accepts that
            raw = bytes(r.data[r.pos : r.end]).split(b"\0", 1)[0]
            r.pos = r.end
            return cls(Sender(raw.decode("utf-8", errors="replace")))
        sender = Sender.read(r)
        sub, bv = False, None
        if r.remaining() >= 5:
            sub = r.data[r.pos] != 0
            r.pos += 1
            got = Version(*r.unpack(_U8x4, "bitstream version"))
            bv = got if got != _V0 else None
        return cls(sender, sub, bv)


@dataclass(frozen=True)
class Discovery(Connect):
    """Client broadcast looking for servers; same layout as CONNECT."""

    ID: ClassVar[int] = MessageId.DISCOVERY


@dataclass(frozen=True)
class ServerInfo:
    """Server → client reply to CONNECT/DISCOVERY. ``clock_frequency`` is the QPC tick rate (ticks/s)."""

    sender: Sender
    clock_frequency: int | None = None
    data_port: int | None = None
    multicast: bool | None = None
    multicast_group: str | None = None

    ID: ClassVar[int] = MessageId.SERVERINFO

    @property
    def app_name(self) -> str:
        return self.sender.name

    @property
    def app_version(self) -> Version:
        return self.sender.version

    @property
    def natnet_version(self) -> Version:
        return self.sender.natnet_version

    def payload(self, version: Version | None = None) -> bytes:
        out = self.sender.pack()
        if self.clock_frequency is not None:
            group = [int(p) for p in (self.multicast_group or "0.0.0.0").split(".")]
            out += _SERVER_TAIL.pack(self.clock_frequency, self.data_port or 0, bool(self.multicast), *group)
        return out

    @classmethod
    def parse(cls, r: _Reader, version: Version | None) -> ServerInfo:
        sender = Sender.read(r)
        if r.remaining() < _SERVER_TAIL.size:  # pre-3.0 servers send the sender block only
            return cls(sender)
        freq, port, mc, *grp = r.unpack(_SERVER_TAIL, "server connection info")
        return cls(sender, freq, port, mc, ".".join(str(g) for g in grp))


@dataclass(frozen=True)
class Request:
    """A text command to the server, e.g. ``"FrameRate"`` or ``"Bitstream,4.1"``."""

    command: str

    ID: ClassVar[int] = MessageId.REQUEST

    def payload(self, version: Version | None = None) -> bytes:
        return _cstr(self.command)

    @classmethod
    def parse(cls, r: _Reader, version: Version | None) -> Request:
        i = r.data.find(b"\0", r.pos, r.end)  # Motive sends bytes after the NUL; tolerate a missing NUL too
        raw = bytes(r.data[r.pos : r.end if i < 0 else i])
        r.pos = r.end
        return cls(raw.decode("utf-8", errors="replace"))


@dataclass(frozen=True)
class Response:
    """Server reply to a :class:`Request`: 4 bytes (int or float, by command) or a NUL-terminated string."""

    payload_bytes: bytes = b""

    ID: ClassVar[int] = MessageId.RESPONSE

    def payload(self, version: Version | None = None) -> bytes:
        return self.payload_bytes

    @classmethod
    def parse(cls, r: _Reader, version: Version | None) -> Response:
        return cls(r.rest())

    @classmethod
    def of_int(cls, value: int) -> Response:
        return cls(_I32.pack(value))

    @classmethod
    def of_float(cls, value: float) -> Response:
        return cls(_F32.pack(value))

    @classmethod
    def of_text(cls, text: str) -> Response:
        return cls(_cstr(text))

    def as_int(self) -> int:
        if len(self.payload_bytes) != 4:
            raise NatNetParseError(f"response is {len(self.payload_bytes)} bytes, not a 4-byte int")
        return _I32.unpack(self.payload_bytes)[0]

    def as_float(self) -> float:
        if len(self.payload_bytes) != 4:
            raise NatNetParseError(f"response is {len(self.payload_bytes)} bytes, not a 4-byte float")
        return _F32.unpack(self.payload_bytes)[0]

    def as_text(self) -> str:
        return self.payload_bytes.split(b"\0", 1)[0].decode("utf-8", errors="replace")


@dataclass(frozen=True)
class MessageString:
    text: str

    ID: ClassVar[int] = MessageId.MESSAGESTRING

    def payload(self, version: Version | None = None) -> bytes:
        return _cstr(self.text)

    @classmethod
    def parse(cls, r: _Reader, version: Version | None) -> MessageString:
        return cls(Response(r.rest()).as_text())


@dataclass(frozen=True)
class _Empty:
    """A message without payload (any payload received is ignored)."""

    def payload(self, version: Version | None = None) -> bytes:
        return b""

    @classmethod
    def parse(cls, r: _Reader, version: Version | None):
        r.pos = r.end
        return cls()


@dataclass(frozen=True)
class RequestModelDef(_Empty):
    ID: ClassVar[int] = MessageId.REQUEST_MODELDEF


@dataclass(frozen=True)
class RequestFrameOfData(_Empty):
    ID: ClassVar[int] = MessageId.REQUEST_FRAMEOFDATA


@dataclass(frozen=True)
class Disconnect(_Empty):
    ID: ClassVar[int] = MessageId.DISCONNECT


@dataclass(frozen=True)
class KeepAlive(_Empty):
    """Unicast clients send this periodically so the server keeps streaming to them."""

    ID: ClassVar[int] = MessageId.KEEPALIVE


@dataclass(frozen=True)
class DisconnectByTimeout(_Empty):
    ID: ClassVar[int] = MessageId.DISCONNECTBYTIMEOUT


@dataclass(frozen=True)
class UnrecognizedRequest:
    """Server reply to a command it does not know (Motive fills the payload with stale bytes)."""

    payload_bytes: bytes = b""

    ID: ClassVar[int] = MessageId.UNRECOGNIZED_REQUEST

    def payload(self, version: Version | None = None) -> bytes:
        return self.payload_bytes

    @classmethod
    def parse(cls, r: _Reader, version: Version | None) -> UnrecognizedRequest:
        return cls(r.rest())


@dataclass(frozen=True)
class EchoRequest:
    """Client → server: an opaque 64-bit client timestamp the server echoes back."""

    client_stamp: int

    ID: ClassVar[int] = MessageId.ECHOREQUEST

    def payload(self, version: Version | None = None) -> bytes:
        return _U64.pack(self.client_stamp)

    @classmethod
    def parse(cls, r: _Reader, version: Version | None) -> EchoRequest:
        return cls(r.unpack(_U64, "echo request stamp")[0])


@dataclass(frozen=True)
class EchoResponse:
    """Server → client: the request's client stamp and the server's QPC ticks when it received the request."""

    client_stamp: int
    server_stamp: int

    ID: ClassVar[int] = MessageId.ECHORESPONSE

    def payload(self, version: Version | None = None) -> bytes:
        return _U64.pack(self.client_stamp) + _U64.pack(self.server_stamp)

    @classmethod
    def parse(cls, r: _Reader, version: Version | None) -> EchoResponse:
        a = r.unpack(_U64, "echo response client stamp")[0]
        b = r.unpack(_U64, "echo response server stamp")[0]
        return cls(a, b)


# --------------------------------------------------------------------------------------------- MODELDEF


@dataclass(frozen=True)
class MarkerSetDescription:
    name: str
    marker_names: tuple[str, ...] = ()

    TYPE: ClassVar[int] = 0

    def pack(self, v: Version) -> bytes:
        return _cstr(self.name) + _I32.pack(len(self.marker_names)) + b"".join(_cstr(n) for n in self.marker_names)

    @classmethod
    def read(cls, r: _Reader, v: Version) -> MarkerSetDescription:
        name = r.cstring("marker set name")
        n = r.count("marker name count", 1)
        return cls(name, tuple(r.cstring("marker name") for _ in range(n)))


@dataclass(frozen=True)
class RigidBodyMarker:
    offset: Vec3
    active_label: int = 0
    name: str = ""  # NatNet >= 4.0


@dataclass(frozen=True)
class RigidBodyDescription:
    name: str
    id: int
    parent_id: int = -1
    offset: Vec3 = (0.0, 0.0, 0.0)
    markers: tuple[RigidBodyMarker, ...] = ()

    TYPE: ClassVar[int] = 1

    def pack(self, v: Version) -> bytes:
        out = [_cstr(self.name), _I32.pack(self.id), _I32.pack(self.parent_id), _V3.pack(*self.offset)]
        out.append(_I32.pack(len(self.markers)))
        out += [_V3.pack(*m.offset) for m in self.markers]
        out += [_I32.pack(m.active_label) for m in self.markers]
        if v >= V4_0:
            out += [_cstr(m.name) for m in self.markers]
        return b"".join(out)

    @classmethod
    def read(cls, r: _Reader, v: Version) -> RigidBodyDescription:
        name = r.cstring("rigid body name")
        rb_id = r.i32("rigid body id")
        parent = r.i32("rigid body parent id")
        offset = r.unpack(_V3, "rigid body offset")
        n = r.count("rigid body marker count", 16)
        offsets = [r.unpack(_V3, "rigid body marker offset") for _ in range(n)]
        labels = [r.i32("rigid body marker label") for _ in range(n)]
        names = [r.cstring("rigid body marker name") for _ in range(n)] if v >= V4_0 else [""] * n
        markers = tuple(RigidBodyMarker(o, lab, nm) for o, lab, nm in zip(offsets, labels, names))
        return cls(name, rb_id, parent, offset, markers)


@dataclass(frozen=True)
class SkeletonDescription:
    name: str
    id: int
    rigid_bodies: tuple[RigidBodyDescription, ...] = ()

    TYPE: ClassVar[int] = 2

    def pack(self, v: Version) -> bytes:
        head = _cstr(self.name) + _I32.pack(self.id) + _I32.pack(len(self.rigid_bodies))
        return head + b"".join(rb.pack(v) for rb in self.rigid_bodies)

    @classmethod
    def read(cls, r: _Reader, v: Version) -> SkeletonDescription:
        name = r.cstring("skeleton name")
        sk_id = r.i32("skeleton id")
        n = r.count("skeleton bone count", 25)
        return cls(name, sk_id, tuple(RigidBodyDescription.read(r, v) for _ in range(n)))


@dataclass(frozen=True)
class ForcePlateDescription:
    id: int
    serial: str
    width: float
    length: float
    origin: Vec3
    cal_matrix: tuple[tuple[float, ...], ...]  # 12 × 12
    corners: tuple[Vec3, ...]  # 4 × 3
    plate_type: int
    channel_data_type: int
    channel_names: tuple[str, ...] = ()

    TYPE: ClassVar[int] = 3
    _CAL: ClassVar[struct.Struct] = struct.Struct("<144f")
    _CORNERS: ClassVar[struct.Struct] = struct.Struct("<12f")

    def pack(self, v: Version) -> bytes:
        out = [_I32.pack(self.id), _cstr(self.serial), _F32.pack(self.width), _F32.pack(self.length)]
        out += [_V3.pack(*self.origin), self._CAL.pack(*(x for row in self.cal_matrix for x in row))]
        out += [self._CORNERS.pack(*(x for c in self.corners for x in c))]
        out += [_I32.pack(self.plate_type), _I32.pack(self.channel_data_type), _I32.pack(len(self.channel_names))]
        out += [_cstr(n) for n in self.channel_names]
        return b"".join(out)

    @classmethod
    def read(cls, r: _Reader, v: Version) -> ForcePlateDescription:
        fp_id = r.i32("force plate id")
        serial = r.cstring("force plate serial")
        width = r.unpack(_F32, "force plate width")[0]
        length = r.unpack(_F32, "force plate length")[0]
        origin = r.unpack(_V3, "force plate origin")
        cal = r.unpack(cls._CAL, "force plate calibration matrix")
        corners = r.unpack(cls._CORNERS, "force plate corners")
        plate_type = r.i32("force plate type")
        data_type = r.i32("force plate channel data type")
        n = r.count("force plate channel count", 1)
        names = tuple(r.cstring("force plate channel name") for _ in range(n))
        cal_m = tuple(tuple(cal[i * 12 : i * 12 + 12]) for i in range(12))
        corner_t = tuple(tuple(corners[i * 3 : i * 3 + 3]) for i in range(4))
        return cls(fp_id, serial, width, length, origin, cal_m, corner_t, plate_type, data_type, names)


@dataclass(frozen=True)
class DeviceDescription:
    id: int
    name: str
    serial: str
    device_type: int
    channel_data_type: int
    channel_names: tuple[str, ...] = ()

    TYPE: ClassVar[int] = 4

    def pack(self, v: Version) -> bytes:
        out = [_I32.pack(self.id), _cstr(self.name), _cstr(self.serial), _I32.pack(self.device_type)]
        out += [_I32.pack(self.channel_data_type), _I32.pack(len(self.channel_names))]
        out += [_cstr(n) for n in self.channel_names]
        return b"".join(out)

    @classmethod
    def read(cls, r: _Reader, v: Version) -> DeviceDescription:
        dev_id = r.i32("device id")
        name = r.cstring("device name")
        serial = r.cstring("device serial")
        dev_type = r.i32("device type")
        data_type = r.i32("device channel data type")
        n = r.count("device channel count", 1)
        return cls(dev_id, name, serial, dev_type, data_type, tuple(r.cstring("device channel name") for _ in range(n)))


@dataclass(frozen=True)
class CameraDescription:
    name: str
    position: Vec3
    orientation: Quat

    TYPE: ClassVar[int] = 5

    def pack(self, v: Version) -> bytes:
        return _cstr(self.name) + _V3.pack(*self.position) + _V4.pack(*self.orientation)

    @classmethod
    def read(cls, r: _Reader, v: Version) -> CameraDescription:
        name = r.cstring("camera name")
        return cls(name, r.unpack(_V3, "camera position"), r.unpack(_V4, "camera orientation"))


@dataclass(frozen=True)
class MarkerDescription:
    name: str
    id: int
    position: Vec3
    size: float
    params: int

    _ST: ClassVar[struct.Struct] = struct.Struct("<i3ffh")

    def pack(self) -> bytes:
        return _cstr(self.name) + self._ST.pack(self.id, *self.position, self.size, self.params)

    @classmethod
    def read(cls, r: _Reader) -> MarkerDescription:
        name = r.cstring("asset marker name")
        mk_id, x, y, z, size, params = r.unpack(cls._ST, "asset marker description")
        return cls(name, mk_id, (x, y, z), size, params)


@dataclass(frozen=True)
class AssetDescription:
    name: str
    asset_type: int
    id: int
    rigid_bodies: tuple[RigidBodyDescription, ...] = ()
    markers: tuple[MarkerDescription, ...] = ()

    TYPE: ClassVar[int] = 6

    def pack(self, v: Version) -> bytes:
        out = [_cstr(self.name), _I32.pack(self.asset_type), _I32.pack(self.id), _I32.pack(len(self.rigid_bodies))]
        out += [rb.pack(v) for rb in self.rigid_bodies]
        out += [_I32.pack(len(self.markers))] + [m.pack() for m in self.markers]
        return b"".join(out)

    @classmethod
    def read(cls, r: _Reader, v: Version) -> AssetDescription:
        name = r.cstring("asset name")
        a_type = r.i32("asset type")
        a_id = r.i32("asset id")
        n_rb = r.count("asset rigid body count", 25)
        rbs = tuple(RigidBodyDescription.read(r, v) for _ in range(n_rb))
        n_mk = r.count("asset marker count", 23)
        return cls(name, a_type, a_id, rbs, tuple(MarkerDescription.read(r) for _ in range(n_mk)))


@dataclass(frozen=True)
class UnknownDescription:
    """A MODELDEF entry of a type this codec does not know (only skippable in NatNet >= 4.1)."""

    type: int
    raw: bytes

    def pack(self, v: Version) -> bytes:
        return self.raw


Description = (
    MarkerSetDescription
    | RigidBodyDescription
    | SkeletonDescription
    | ForcePlateDescription
    | DeviceDescription
    | CameraDescription
    | AssetDescription
    | UnknownDescription
)
_DESCRIPTIONS = {
    c.TYPE: c
    for c in (
        MarkerSetDescription,
        RigidBodyDescription,
        SkeletonDescription,
        ForcePlateDescription,
        DeviceDescription,
        CameraDescription,
        AssetDescription,
    )
}


@dataclass(frozen=True)
class ModelDef:
    """The data descriptions (MODELDEF): marker sets, rigid bodies, skeletons, devices, cameras, assets."""

    datasets: tuple[Description, ...] = ()

    ID: ClassVar[int] = MessageId.MODELDEF

    def payload(self, version: Version | None = None) -> bytes:
        v = _check_version(version)
        out = [_I32.pack(len(self.datasets))]
        for d in self.datasets:
            body = d.pack(v)
            out.append(_I32.pack(d.type if isinstance(d, UnknownDescription) else d.TYPE))
            if _has_sizes(v):
                out.append(_I32.pack(len(body)))
            out.append(body)
        return b"".join(out)

    @classmethod
    def parse(cls, r: _Reader, version: Version | None) -> ModelDef:
        v = _check_version(version)
        n = r.count("dataset count", 4)
        out: list[Description] = []
        for _ in range(n):
            d_type = r.i32("dataset type")
            if _has_sizes(v):
                size = r.count("dataset size", 1)
                sub = _Reader(r.data, r.pos, r.pos + size)
                r.pos += size
                kind = _DESCRIPTIONS.get(d_type)
                if kind is None:
                    out.append(UnknownDescription(d_type, sub.rest()))
                else:
                    out.append(kind.read(sub, v))  # extra bytes in an entry are fields newer than 4.1: skipped
            else:
                kind = _DESCRIPTIONS.get(d_type)
                if kind is None:
                    raise NatNetParseError(
                        f"unknown MODELDEF dataset type {d_type} (NatNet {v} has no sizes to skip it)"
                    )
                out.append(kind.read(r, v))
        return cls(tuple(out))

    def marker_sets(self) -> list[MarkerSetDescription]:
        return [d for d in self.datasets if isinstance(d, MarkerSetDescription)]

    def rigid_bodies(self) -> list[RigidBodyDescription]:
        return [d for d in self.datasets if isinstance(d, RigidBodyDescription)]


# --------------------------------------------------------------------------------------------- FRAMEOFDATA


class LabeledMarker(NamedTuple):
    """One labeled marker of a frame. ``id`` packs the model (asset) id in the high 16 bits."""

    id: int
    position: Vec3
    size: float
    params: int
    residual: float

    @property
    def model_id(self) -> int:
        return self.id >> 16

    @property
    def marker_id(self) -> int:
        return self.id & 0xFFFF

    @property
    def occluded(self) -> bool:
        return bool(self.params & 0x01)

    @property
    def point_cloud_solved(self) -> bool:
        return bool(self.params & 0x02)

    @property
    def model_solved(self) -> bool:
        return bool(self.params & 0x04)

    @property
    def has_model(self) -> bool:
        return bool(self.params & 0x08)

    @property
    def unlabeled(self) -> bool:
        return bool(self.params & 0x10)

    @property
    def active(self) -> bool:
        return bool(self.params & 0x20)


class RigidBody(NamedTuple):
    """One rigid body of a frame; ``params`` bit 0 is "tracking valid"."""

    id: int
    position: Vec3
    orientation: Quat  # qx, qy, qz, qw
    error: float
    params: int

    @property
    def tracking_valid(self) -> bool:
        return bool(self.params & 0x01)


class MarkerSetData(NamedTuple):
    name: str
    positions: tuple[Vec3, ...]


class SkeletonData(NamedTuple):
    id: int
    rigid_bodies: tuple[RigidBody, ...]


class AssetMarker(NamedTuple):
    id: int
    position: Vec3
    size: float
    params: int
    residual: float


class AssetData(NamedTuple):
    id: int
    rigid_bodies: tuple[RigidBody, ...]
    markers: tuple[AssetMarker, ...]


class AnalogData(NamedTuple):
    """A force plate or device: per channel, the analog sub-frames of this mocap frame."""

    id: int
    channels: tuple[tuple[float, ...], ...]


SECTIONS = (
    "marker_sets",
    "other_markers",
    "rigid_bodies",
    "skeletons",
    "assets",
    "labeled_markers",
    "force_plates",
    "devices",
)


def _rb_from(t: tuple) -> RigidBody:
    return RigidBody(t[0], (t[1], t[2], t[3]), (t[4], t[5], t[6], t[7]), t[8], t[9])


def _read_rbs(r: _Reader, n: int, what: str) -> tuple[RigidBody, ...]:
    r.need(n * _RB.size, what)
    start = r.pos
    r.pos += n * _RB.size
    return tuple(_rb_from(t) for t in _RB.iter_unpack(r.data[start : r.pos]))


def _pack_rbs(rbs: tuple[RigidBody, ...]) -> bytes:
    return b"".join(_RB.pack(b.id, *b.position, *b.orientation, b.error, b.params) for b in rbs)


def _read_analog(r: _Reader, what: str) -> AnalogData:
    a_id = r.i32(f"{what} id")
    n_ch = r.count(f"{what} channel count", 4)
    channels = []
    for _ in range(n_ch):
        n = r.count(f"{what} sub-frame count", 4)
        st = struct.Struct(f"<{n}f")
        channels.append(r.unpack(st, f"{what} samples"))
    return AnalogData(a_id, tuple(channels))


def _pack_analog(a: AnalogData) -> bytes:
    out = [_I32.pack(a.id), _I32.pack(len(a.channels))]
    for ch in a.channels:
        out.append(_I32.pack(len(ch)) + struct.pack(f"<{len(ch)}f", *ch))
    return b"".join(out)


@dataclass(frozen=True)
class FrameOfData:
    """One mocap frame. Timestamps: ``timestamp`` (s, Motive's frame time); QPC ticks ``mid_exposure``,
    ``data_received``, ``transmit`` (NatNet >= 3.0); ``precision_seconds``/``precision_fraction`` (>= 4.1)."""

    frame_number: int
    marker_sets: tuple[MarkerSetData, ...] = ()
    other_markers: tuple[Vec3, ...] = ()
    rigid_bodies: tuple[RigidBody, ...] = ()
    skeletons: tuple[SkeletonData, ...] = ()
    assets: tuple[AssetData, ...] = ()
    labeled_markers: tuple[LabeledMarker, ...] = ()
    force_plates: tuple[AnalogData, ...] = ()
    devices: tuple[AnalogData, ...] = ()
    timecode: int = 0
    timecode_sub: int = 0
    timestamp: float = 0.0
    mid_exposure: int = 0
    data_received: int = 0
    transmit: int = 0
    precision_seconds: int | None = None
    precision_fraction: int | None = None
    params: int = 0
    section_sizes: tuple[int, ...] | None = field(default=None, compare=False)  # as received (4.1+)

    ID: ClassVar[int] = MessageId.FRAMEOFDATA

    @property
    def is_recording(self) -> bool:
        return bool(self.params & 0x01)

    @property
    def tracked_models_changed(self) -> bool:
        return bool(self.params & 0x02)

    @property
    def timecode_string(self) -> str:
        """SMPTE ``hh:mm:ss:ff.sub`` as the SDK prints it."""
        t = self.timecode
        return f"{(t >> 24) & 255:02d}:{(t >> 16) & 255:02d}:{(t >> 8) & 255:02d}:{t & 255:02d}.{self.timecode_sub}"

    # -- decode

    @classmethod
    def parse(cls, r: _Reader, version: Version | None) -> FrameOfData:
        v = _check_version(version)
        sizes = _has_sizes(v)
        got_sizes: list[int] = []
        frame_number = r.i32("frame number")

        def section(what: str, min_item: int):
            n = r.count(f"{what} count", min_item)
            if not sizes:
                return n, None
            size = r.count(f"{what} size", 1)
            got_sizes.append(size)
            return n, r.pos + size

        def close(what: str, end: int | None) -> None:
            if end is None:
                return
            if r.pos > end:
                raise NatNetParseError(f"{what} overran its declared size by {r.pos - end} bytes")
            r.pos = end  # fields newer than this version: skipped

        n, end = section("marker set", 5)
        msets = []
        for _ in range(n):
            name = r.cstring("marker set name")
            m = r.count("marker set marker count", 12)
            r.need(12 * m, "marker set positions")
            pos = tuple(_V3.iter_unpack(r.data[r.pos : r.pos + 12 * m]))
            r.pos += 12 * m
            msets.append(MarkerSetData(name, pos))
        close("marker sets", end)

        n, end = section("other marker", 12)
        r.need(12 * n, "other markers")
        others = tuple(_V3.iter_unpack(r.data[r.pos : r.pos + 12 * n]))
        r.pos += 12 * n
        close("other markers", end)

        n, end = section("rigid body", _RB.size)
        rbs = _read_rbs(r, n, "rigid bodies")
        close("rigid bodies", end)

        n, end = section("skeleton", 8)
        skels = []
        for _ in range(n):
            sk_id = r.i32("skeleton id")
            m = r.count("skeleton bone count", _RB.size)
            skels.append(SkeletonData(sk_id, _read_rbs(r, m, "skeleton bones")))
        close("skeletons", end)

        assets = []
        if v >= V4_1:
            n, end = section("asset", 12)
            for _ in range(n):
                a_id = r.i32("asset id")
                m = r.count("asset rigid body count", _ASSET_RB.size)
                a_rbs = _read_rbs(r, m, "asset rigid bodies")
                k = r.count("asset marker count", _ASSET_MK.size)
                r.need(k * _ASSET_MK.size, "asset markers")
                mks = tuple(
                    AssetMarker(t[0], (t[1], t[2], t[3]), t[4], t[5], t[6])
                    for t in _ASSET_MK.iter_unpack(r.data[r.pos : r.pos + k * _ASSET_MK.size])
                )
                r.pos += k * _ASSET_MK.size
                assets.append(AssetData(a_id, a_rbs, mks))
            close("assets", end)

        n, end = section("labeled marker", _LM.size)
        r.need(n * _LM.size, "labeled markers")
        lms = tuple(
            LabeledMarker(t[0], (t[1], t[2], t[3]), t[4], t[5], t[6])
            for t in _LM.iter_unpack(r.data[r.pos : r.pos + n * _LM.size])
        )
        r.pos += n * _LM.size
        close("labeled markers", end)

        n, end = section("force plate", 8)
        plates = tuple(_read_analog(r, "force plate") for _ in range(n))
        close("force plates", end)

        n, end = section("device", 8)
        devices = tuple(_read_analog(r, "device") for _ in range(n))
        close("devices", end)

        tc, tc_sub, ts, mid, recv, tx = r.unpack(_SUFFIX_TIMES, "frame suffix")
        p_s = p_f = None
        if v >= V4_1:
            p_s, p_f = r.unpack(_PRECISION, "precision timestamp")
        params = r.unpack(_I16, "frame params")[0]
        if r.remaining() == 4:  # Motive ends frames with a 4-byte end-of-data tag (0); tolerate its absence
            r.pos += 4
        return cls(
            frame_number,
            tuple(msets),
            others,
            rbs,
            tuple(skels),
            tuple(assets),
            lms,
            plates,
            devices,
            tc,
            tc_sub,
            ts,
            mid,
            recv,
            tx,
            p_s,
            p_f,
            params,
            tuple(got_sizes) if sizes else None,
        )

    # -- encode

    def payload(self, version: Version | None = None) -> bytes:
        v = _check_version(version)
        sizes = _has_sizes(v)
        out = [_I32.pack(self.frame_number)]

        def put(count: int, body: bytes) -> None:
            out.append(_I32.pack(count))
            if sizes:
                out.append(_I32.pack(len(body)))
            out.append(body)

        put(
            len(self.marker_sets),
            b"".join(
                _cstr(ms.name) + _I32.pack(len(ms.positions)) + b"".join(_V3.pack(*p) for p in ms.positions)
                for ms in self.marker_sets
            ),
        )
        put(len(self.other_markers), b"".join(_V3.pack(*p) for p in self.other_markers))
        put(len(self.rigid_bodies), _pack_rbs(self.rigid_bodies))
        put(
            len(self.skeletons),
            b"".join(
                _I32.pack(s.id) + _I32.pack(len(s.rigid_bodies)) + _pack_rbs(s.rigid_bodies) for s in self.skeletons
            ),
        )
        if v >= V4_1:
            put(
                len(self.assets),
                b"".join(
                    _I32.pack(a.id)
                    + _I32.pack(len(a.rigid_bodies))
                    + _pack_rbs(a.rigid_bodies)
                    + _I32.pack(len(a.markers))
                    + b"".join(_ASSET_MK.pack(m.id, *m.position, m.size, m.params, m.residual) for m in a.markers)
                    for a in self.assets
                ),
            )
        put(
            len(self.labeled_markers),
            b"".join(_LM.pack(m.id, *m.position, m.size, m.params, m.residual) for m in self.labeled_markers),
        )
        put(len(self.force_plates), b"".join(_pack_analog(a) for a in self.force_plates))
        put(len(self.devices), b"".join(_pack_analog(a) for a in self.devices))
        out.append(
            _SUFFIX_TIMES.pack(
                self.timecode, self.timecode_sub, self.timestamp, self.mid_exposure, self.data_received, self.transmit
            )
        )
        if v >= V4_1:
            out.append(_PRECISION.pack(self.precision_seconds or 0, self.precision_fraction or 0))
        out.append(_I16.pack(self.params))
        out.append(_I32.pack(0))  # end-of-data tag
        return b"".join(out)


# --------------------------------------------------------------------------------------------- dispatch

Message = (
    Connect
    | Discovery
    | ServerInfo
    | Request
    | Response
    | RequestModelDef
    | ModelDef
    | RequestFrameOfData
    | FrameOfData
    | MessageString
    | Disconnect
    | KeepAlive
    | DisconnectByTimeout
    | EchoRequest
    | EchoResponse
    | UnrecognizedRequest
)
_MESSAGES: dict[int, Any] = {
    c.ID: c
    for c in (
        Connect,
        Discovery,
        ServerInfo,
        Request,
        Response,
        RequestModelDef,
        ModelDef,
        RequestFrameOfData,
        FrameOfData,
        MessageString,
        Disconnect,
        KeepAlive,
        DisconnectByTimeout,
        EchoRequest,
        EchoResponse,
        UnrecognizedRequest,
    )
}


def peek_message_id(packet: bytes) -> int:
    """The message id of a packet (without decoding it)."""
    if len(packet) < 2:
        raise NatNetParseError(f"packet of {len(packet)} bytes has no header")
    return packet[0] | packet[1] << 8


def decode(packet: bytes, version: Version | tuple | None = None) -> Message:
    """Decode one UDP payload. ``version`` (the stream's NatNet version) is needed for MODELDEF and frames.

    Bytes after the header's declared payload size are ignored; a payload shorter than declared, a payload with
    bytes left over inside a frame, or any inconsistency raises :class:`NatNetParseError`.
    """
    if not isinstance(packet, (bytes, bytearray, memoryview)):
        raise NatNetParseError(f"expected bytes, got {type(packet).__name__}")
    packet = bytes(packet)
    if len(packet) < 4:
        raise NatNetParseError(f"packet of {len(packet)} bytes is shorter than the 4-byte header")
    msg_id, size = _HEADER.unpack_from(packet, 0)
    if 4 + size > len(packet):
        raise NatNetParseError(f"message {msg_id} declares {size} payload bytes, only {len(packet) - 4} present")
    kind = _MESSAGES.get(msg_id)
    if kind is None:
        raise NatNetParseError(f"unknown message id {msg_id}")
    v = Version(*version) if version is not None else None
    r = _Reader(packet, 4, 4 + size)
    msg: Message = kind.parse(r, v)  # every message class has parse(reader, version)
    if kind is FrameOfData and r.pos != r.end and v is not None and v <= V4_1:  # newer versions may append
        raise NatNetParseError(f"frame of data has {r.end - r.pos} unparsed bytes (wrong NatNet version?)")
    return msg


def encode(message: Message, version: Version | tuple | None = None) -> bytes:
    """One message → one UDP payload (header included). ``version`` is needed for MODELDEF and frames."""
    v = Version(*version) if version is not None else None
    payload = message.payload(v)
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"{type(message).__name__} payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    return _HEADER.pack(message.ID, len(payload)) + payload
