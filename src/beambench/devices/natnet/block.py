"""Many NatNet frames at once: numpy over the bytes of frames that share one layout.

A steady Motive stream sends frames of one layout: the same sections with the same counts, sizes and names;
only the values change. :func:`frame_layout` decodes one packet with the full codec (:mod:`~beambench.devices.natnet.protocol`)
while noting where every count, size and name lies (the bytes that decide where everything else is) and where
the values the mocap stream needs sit. :func:`decode_block` stacks packets of that length, compares those bytes
of all of them at once, and reads the values of every packet that matches as arrays. A packet that does not
match is not decoded here: the caller gives it to the full codec, which decodes or rejects it exactly as it
would alone. The values are the codec's, bit for bit (tests), at a fraction of the cost per frame
(``python benchmarks/bench_natnet.py``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from beambench.devices.natnet import frame as nf
from beambench.devices.natnet import protocol as nn
from beambench.devices.natnet import wire as nw

__all__ = ["FrameBlock", "FrameLayout", "decode_block", "frame_layout"]

LABELED_MARKER = np.dtype(
    [("id", "<i4"), ("position", "<f4", (3,)), ("size", "<f4"), ("params", "<i2"), ("residual", "<f4")]
)
RIGID_BODY = np.dtype(
    [
        ("id", "<i4"),
        ("position", "<f4", (3,)),
        ("orientation", "<f4", (4,)),
        ("error", "<f4"),
        ("params", "<i2"),
    ]
)
SUFFIX = np.dtype(
    [
        ("timecode", "<u4"),
        ("timecode_sub", "<u4"),
        ("timestamp", "<f8"),
        ("mid_exposure", "<u8"),
        ("data_received", "<u8"),
        ("transmit", "<u8"),
    ]
)
_HEADER_BYTES = 4
_FRAME_NUMBER = struct.Struct("<i")


class _Recorder(nw._Reader):
    """The codec's reader, noting the bytes that decide the layout (counts, sizes, names) and where fields are."""

    __slots__ = ("at", "structure")

    def __init__(self, data: bytes, pos: int, end: int) -> None:
        super().__init__(data, pos, end)
        self.structure: list[tuple[int, int]] = [(0, _HEADER_BYTES)]  # message id and payload size
        self.at: dict[str, int] = {}  # a field's name → the offset just after it (counts) or at it (unpack)

    def count(self, what: str, min_item_size: int) -> int:
        self.structure.append((self.pos, 4))
        n = super().count(what, min_item_size)
        self.at[what] = self.pos
        return n

    def cstring(self, what: str) -> str:
        start = self.pos
        s = super().cstring(what)
        self.structure.append((start, self.pos - start))
        return s

    def unpack(self, st: struct.Struct, what: str) -> tuple:
        self.at[what] = self.pos
        return super().unpack(st, what)


@dataclass(frozen=True)
class FrameLayout:
    """Where one layout's fields lie in a packet of ``length`` bytes of NatNet ``version``."""

    length: int
    version: nw.Version
    structure: np.ndarray  # byte offsets that decide the layout
    signature: np.ndarray  # their values in every packet of this layout
    labeled_markers: tuple[int, int]  # offset, count
    rigid_bodies: tuple[int, int]
    suffix: int  # offset of the frame suffix's times
    spans: tuple[tuple[int, int, bytes], ...]  # the structure as runs of bytes: (start, end, expected)

    def fits(self, packet: bytes) -> bool:
        """Does one packet have this layout? (The check :func:`decode_block` makes, for a single packet.)"""
        return len(packet) == self.length and all(packet[a:b] == want for a, b, want in self.spans)


def frame_layout(packet: bytes, version: nw.Version) -> FrameLayout:
    """The layout of one FRAMEOFDATA packet; :class:`~beambench.devices.natnet.protocol.NatNetParseError` if it does not decode."""
    packet = bytes(packet)
    if len(packet) < _HEADER_BYTES:
        raise nw.NatNetParseError(f"packet of {len(packet)} bytes is shorter than the 4-byte header")
    msg_id, size = struct.unpack_from("<HH", packet, 0)
    if msg_id != nw.MessageId.FRAMEOFDATA:
        raise nw.NatNetParseError(f"message {msg_id} is not a frame of data")
    nn.decode(packet, version)  # every check the codec makes, with its messages
    r = _Recorder(packet, _HEADER_BYTES, _HEADER_BYTES + size)
    nf.FrameOfData.parse(r, version)
    sized = version >= nw.V4_1

    def section(what: str) -> tuple[int, int]:
        n = _FRAME_NUMBER.unpack_from(packet, r.at[f"{what} count"] - 4)[0]
        return (r.at[f"{what} size"] if sized else r.at[f"{what} count"]), n

    offsets = np.unique(np.concatenate([np.arange(o, o + k) for o, k in r.structure]))
    breaks = np.flatnonzero(np.diff(offsets) != 1) + 1
    spans = tuple((int(run[0]), int(run[-1]) + 1, packet[run[0] : run[-1] + 1]) for run in np.split(offsets, breaks))
    return FrameLayout(
        length=len(packet),
        version=version,
        structure=offsets,
        signature=np.frombuffer(packet, np.uint8)[offsets].copy(),
        labeled_markers=section("labeled marker"),
        rigid_bodies=section("rigid body"),
        suffix=r.at["frame suffix"],
        spans=spans,
    )


@dataclass(frozen=True)
class FrameBlock:
    """The values of ``len(self)`` frames of one layout, in the order given."""

    frame_number: np.ndarray  # int64
    suffix: np.ndarray  # SUFFIX records (timestamp, mid_exposure, …)
    labeled_markers: np.ndarray  # (frames, markers) LABELED_MARKER records
    rigid_bodies: np.ndarray  # (frames, bodies) RIGID_BODY records

    def __len__(self) -> int:
        return len(self.frame_number)


def decode_block(packets: list[bytes], layout: FrameLayout) -> tuple[FrameBlock, np.ndarray]:
    """The frames among ``packets`` that have ``layout`` (``matches``, a bool per packet), as arrays.

    Packets of another length or another layout are marked ``False``: decode those one by one with the codec.
    """
    # The layout's bytes of every packet of the right length, gathered with ``np.take`` and compared row by row
    # as bytes: no ufunc, so no iterator buffer allocated with the GIL released (numpy turns a failed buffer
    # allocation there into a fatal error, not a MemoryError: the process would die while the motor turns).
    sized = [p for p in packets if len(p) == layout.length]
    head = np.frombuffer(b"".join(sized), np.uint8).reshape(len(sized), layout.length)
    picked = np.take(head, layout.structure, axis=1).tobytes()
    signature, k = layout.signature.tobytes(), len(layout.structure)
    fits = iter([picked[i : i + k] == signature for i in range(0, len(picked), k)])
    matches = np.fromiter((len(p) == layout.length and next(fits) for p in packets), dtype=bool, count=len(packets))
    raw = np.frombuffer(b"".join(p for p, ok in zip(packets, matches, strict=True) if ok), np.uint8)
    raw = raw.reshape(-1, layout.length)

    def records(offset: int, count: int, dtype: np.dtype) -> np.ndarray:
        block = np.ascontiguousarray(raw[:, offset : offset + count * dtype.itemsize])
        return block.view(dtype).reshape(len(raw), count)

    start = _HEADER_BYTES
    frame_number = np.ascontiguousarray(raw[:, start : start + 4]).view("<i4")[:, 0].astype(np.int64)
    return (
        FrameBlock(
            frame_number=frame_number,
            suffix=records(layout.suffix, 1, SUFFIX)[:, 0],
            labeled_markers=records(*layout.labeled_markers, LABELED_MARKER),
            rigid_bodies=records(*layout.rigid_bodies, RIGID_BODY),
        ),
        matches,
    )
