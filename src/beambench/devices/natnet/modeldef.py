"""NatNet MODELDEF: the data descriptions (marker sets, rigid bodies, skeletons, force plates, devices, cameras,
markers, assets), one dataclass each, parsed and packed per version."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import ClassVar

from beambench.devices.natnet.wire import (
    _F32,
    _I32,
    _V3,
    _V4,
    V4_0,
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
