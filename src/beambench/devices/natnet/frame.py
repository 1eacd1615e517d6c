"""NatNet FRAMEOFDATA: one frame of markers, rigid bodies, skeletons, assets, force plates and devices, with its
timestamps; parsed and packed per version."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import ClassVar, NamedTuple

from beambench.devices.natnet.wire import (
    _ASSET_MK,
    _ASSET_RB,
    _I16,
    _I32,
    _LM,
    _PRECISION,
    _RB,
    _SUFFIX_TIMES,
    _V3,
    V4_1,
    MessageId,
    NatNetParseError,
    Quat,
    Vec3,
    Version,
    _check_version,
    _cstr,
    _has_sizes,
    _Reader,
)


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
        msets = _read_marker_sets(r, n)
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

        assets: list[AssetData] = []
        if v >= V4_1:
            n, end = section("asset", 12)
            assets = _read_assets(r, n)
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
        r.need(4, "end-of-data tag")  # Motive ends every frame with a 4-byte tag (0): a frame without it is cut short
        r.pos += 4
        return cls(
            frame_number,
            msets,
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


def _read_marker_sets(r: _Reader, n: int) -> tuple[MarkerSetData, ...]:
    """``n`` marker sets: a name and its markers' positions each."""
    msets = []
    for _ in range(n):
        name = r.cstring("marker set name")
        m = r.count("marker set marker count", 12)
        r.need(12 * m, "marker set positions")
        pos = tuple(_V3.iter_unpack(r.data[r.pos : r.pos + 12 * m]))
        r.pos += 12 * m
        msets.append(MarkerSetData(name, pos))
    return tuple(msets)


def _read_assets(r: _Reader, n: int) -> list[AssetData]:
    """``n`` assets (NatNet 4.1+): an id, its rigid bodies and its markers each."""
    assets = []
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
    return assets
