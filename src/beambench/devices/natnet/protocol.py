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

This module is the codec's face: the small messages and the dispatch are here, the MODELDEF descriptions in
:mod:`.modeldef`, frames of data in :mod:`.frame`, the reader and struct layouts in :mod:`.wire`; import each
name from the module it lives in.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from beambench.devices.natnet.frame import (
    FrameOfData,
)
from beambench.devices.natnet.modeldef import (
    ModelDef,
)
from beambench.devices.natnet.wire import (
    _F32,
    _HEADER,
    _I32,
    _SERVER_TAIL,
    _U64,
    _V0,
    MAX_NAME,
    MAX_PAYLOAD,
    V4_1,
    MessageId,
    NatNetParseError,
    Version,
    _cstr,
    _fixed,
    _Reader,
    _U8x4,
)

__all__ = [
    "Connect",
    "Disconnect",
    "DisconnectByTimeout",
    "Discovery",
    "EchoRequest",
    "EchoResponse",
    "KeepAlive",
    "MessageString",
    "Request",
    "RequestFrameOfData",
    "RequestModelDef",
    "Response",
    "Sender",
    "ServerInfo",
    "UnrecognizedRequest",
    "decode",
    "encode",
    "peek_message_id",
]


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
            raw, nul, rest = bytes(r.data[r.pos : r.end]).partition(b"\0")
            if not nul or rest:  # a sender block cut short, not a name
                raise NatNetParseError(
                    f"connect payload of {r.remaining()} bytes: neither a {Sender.SIZE}-byte sender block nor a name"
                )
            r.pos = r.end
            return cls(Sender(raw.decode("utf-8", errors="replace")))
        sender = Sender.read(r)
        sub, bv = False, None
        if 0 < r.remaining() < 5:
            raise NatNetParseError(f"connect options of {r.remaining()} bytes, not 5 (cut short)")
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
        if r.remaining() == 0 and sender.natnet_version < Version(3):  # pre-3.0 servers send the sender block only
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
