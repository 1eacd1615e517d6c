"""The ``mocap`` stream on a :class:`~beambench.devices.natnet.client.NatNetClient`.

:class:`NatNetMocap` adapts the client to the :class:`beambench.acquisition.capabilities.Stream` seam: batches of
:func:`beambench.acquisition.streams.mocap_spec` (metres, Motive frame number, per-marker occlusion), with a
configurable map from marker names to labeled-marker ids or rigid-body ids (:class:`MarkerSource`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from beambench.acquisition.batch import Batch, Frame, StreamSpec
from beambench.acquisition.capabilities import DeviceFault
from beambench.acquisition.streams import MOCAP, MOCAP_RATE_HZ, mocap_spec
from beambench.devices.base import StreamDriver
from beambench.devices.natnet import block as nb
from beambench.devices.natnet import frame as nf
from beambench.devices.natnet import protocol as nn
from beambench.devices.natnet import wire as nw
from beambench.devices.natnet.client import NatNetClient, NatNetConfig, NatNetStats

__all__ = ["MarkerSource", "NatNetMocap", "default_marker_map"]


@dataclass(frozen=True)
class MarkerSource:
    """Where one named marker comes from: a labeled marker id (model << 16 | marker) or a rigid body id."""

    kind: str  # "marker" | "rigid_body"
    id: int

    @classmethod
    def parse(cls, value: Any) -> MarkerSource:
        """``1:3`` / (1, 3) → model 1 marker 3; ``rb:2`` → rigid body 2; an int → raw labeled-marker id."""
        if isinstance(value, MarkerSource):
            return value
        if isinstance(value, bool):
            raise ValueError(f"not a marker source: {value!r}")
        if isinstance(value, int):
            return cls("marker", value)
        if isinstance(value, (tuple, list)) and len(value) == 2:
            return cls("marker", (int(value[0]) << 16) | (int(value[1]) & 0xFFFF))
        text = str(value).strip().lower()
        if text.startswith(("rb:", "rigid_body:", "rigidbody:")):
            return cls("rigid_body", int(text.split(":", 1)[1]))
        if ":" in text:
            model, marker = text.split(":", 1)
            return cls("marker", (int(model) << 16) | (int(marker) & 0xFFFF))
        return cls("marker", int(text))


def default_marker_map(markers: Sequence[str], model_id: int = 1) -> dict[str, MarkerSource]:
    """Markers in order as labeled markers 1..M of one asset (the emulator's default layout)."""
    return {m: MarkerSource("marker", (model_id << 16) | (i + 1)) for i, m in enumerate(markers)}


class NatNetMocap(StreamDriver):
    """The ``mocap`` stream from Motive: each :meth:`read` returns every frame received since the last one.

    ``device_time`` is the camera mid-exposure time on Motive's QPC clock (ticks / clock frequency, s) when the
    server sends it (``device_time="mid_exposure"``), else Motive's frame timestamp; ``host_time_ns`` is
    ``time.monotonic_ns()`` when the packet arrived. A marker missing from a frame, flagged occluded, or a
    rigid body not tracked, is ``occluded`` with NaN position.

    Liveness: :meth:`check` (and :meth:`read` with nothing to hand out) raise :class:`DeviceFault` once no frame
    arrived for ``silence_timeout_s`` (longer than the mocap monitor's pause, which handles short outages).
    Frames from any sender but the server are dropped and counted (``counters.forged``).

    The receive thread keeps frames undecoded; :meth:`read` decodes the ~36 of a poll together
    (:mod:`beambench.devices.natnet.block`: ~5x cheaper a frame than the codec one by one, the same values),
    falling back to the codec for frames of a layout it has not learned or that do not decode (counted).
    """

    reader_thread = False  # the NatNet client receives in its own thread

    def __init__(
        self,
        markers: Sequence[str],
        config: NatNetConfig | None = None,
        marker_map: Mapping[str, Any] | None = None,
        rate_hz: float | None = None,
        device_time: str = "mid_exposure",
        frame: Frame | None = None,
        silence_timeout_s: float | None = 5.0,
    ) -> None:
        if device_time not in ("mid_exposure", "timestamp"):
            raise ValueError(f"device_time must be 'mid_exposure' or 'timestamp', not {device_time!r}")
        self.markers = tuple(markers)
        raw = marker_map if marker_map is not None else default_marker_map(self.markers)
        missing = [m for m in self.markers if m not in raw]
        if missing:
            raise ValueError(f"marker map has no source for {missing}")
        self.sources = [MarkerSource.parse(raw[m]) for m in self.markers]
        self.config = config or NatNetConfig()
        self.rate_hz = rate_hz
        self.device_time_mode = device_time
        self.client: NatNetClient | None = None
        self.frame = frame or Frame(up_axis="y")  # Motive's default world frame
        super().__init__(MOCAP, mocap_spec(self.markers, rate_hz or MOCAP_RATE_HZ, self.frame), silence_timeout_s)
        self._last_stats = NatNetStats()
        self._last_flood = ""
        self._left_unread = 0  # frames still buffered when the client closed (never read: unrecorded)
        self._layouts: dict[tuple[int, nw.Version], nb.FrameLayout] = {}  # by packet length and version
        self._marker_cols, self._body_cols = self._columns_by_source()

    def _columns_by_source(self) -> tuple[dict[int, list[int]], dict[int, list[int]]]:
        """Labeled-marker id → the stream columns it fills, and rigid-body id → columns (two names may share)."""
        marker_cols: dict[int, list[int]] = {}
        body_cols: dict[int, list[int]] = {}
        for j, src in enumerate(self.sources):
            (marker_cols if src.kind == "marker" else body_cols).setdefault(src.id, []).append(j)
        return marker_cols, body_cols

    @classmethod
    def from_rig(cls, section: Mapping[str, Any], markers: Sequence[str] | None = None, **kw: Any) -> NatNetMocap:
        """From the rig file's ``natnet:`` block: NatNetConfig fields plus ``markers: {name: source}`` where a
        source is ``"model:marker"``, ``"rb:<id>"`` or a raw labeled-marker id (``model << 16 | marker``)."""
        d = dict(section)
        mapping = d.pop("markers", None)
        for key in ("rate_hz", "device_time"):
            if key in d:
                kw.setdefault(key, d.pop(key))
        names = tuple(markers) if markers is not None else tuple(mapping or ())
        if not names:
            raise ValueError("natnet: no markers given (add markers: {name: model:marker} to the rig file)")
        return cls(names, NatNetConfig.from_mapping(d), mapping, **kw)

    def describe(self) -> StreamSpec:
        if self.rate_hz is None and self.client is not None and self.client.frame_rate:
            self._spec = mocap_spec(self.markers, float(self.client.frame_rate), self.frame)
        return self._spec

    def _open(self) -> None:
        if self.client is None:
            self.client = NatNetClient(self.config).connect()
        self.client.raw_frames.clear()
        self._left_unread = 0
        self.client.keep_raw = True  # decoded many at a time in read(): see natnet.block

    def _close(self) -> None:
        if self.client is not None:
            self._left_unread = len(self.client.raw_frames)
            self._sync_counters()
            self.client.close()
            self._last_stats = self.client.stats
            self._last_flood = self.client.refused.flood()
            self.client = None

    def _sync_counters(self) -> None:
        c = self.client
        if c is None:
            return
        st = c.stats
        self.counters.dropped = st.dropped_frames + st.overflowed  # evicted from a full buffer: lost too
        self.counters.garbled = st.parse_errors
        self.counters.forged = st.forged
        if st.last_frame_ns is not None:
            self.last_receive_ns = st.last_frame_ns

    def _unrecorded(self) -> int:
        c = self.client
        return len(c.raw_frames) if c is not None else self._left_unread

    def health(self) -> dict[str, Any]:
        """As every stream's (:meth:`StreamDriver.health`); ``received`` counts frames when :meth:`read` decodes
        them, so the frames still buffered (``unrecorded``) are added: received = stored + unrecorded. ``ignored``:
        datagrams that arrived before the server described itself (not decodable then). ``kernel_dropped``: datagrams
        the kernel dropped unread (a full buffer); ``flood``: a flood named ("" if none)."""
        c = self.client
        if c is not None:
            self._sync_counters()
        out = super().health()
        out["received"] += out["unrecorded"]
        # datagrams that could not be used (frames before the server described itself): arrived, never rows
        out["ignored"] = self.stats.ignored
        out["kernel_dropped"] = self.stats.kernel_dropped
        out["flood"] = c.flood() if c is not None else self._last_flood
        return out

    def echo_sync(self) -> dict[str, Any] | None:
        """The client's ECHO table and the server's clock frequency (``ReportsEchoes``; None while there is no
        client or no server clock)."""
        c = self.client
        if c is None or not c.clock_frequency:
            return None
        table = {k: v.tolist() for k, v in c.echo_table().items()}
        return {**table, "clock_frequency": int(c.clock_frequency)}

    @property
    def stats(self) -> NatNetStats:
        return self.client.stats if self.client is not None else self._last_stats

    @property
    def dropped_frames(self) -> int:
        return self.stats.dropped_frames

    @property
    def parse_errors(self) -> int:
        return self.stats.parse_errors

    def identity(self) -> dict[str, Any]:
        return self.client.info() if self.client is not None else {}

    def check(self) -> None:
        c = self.client
        if c is not None:
            c.check()
            self._sync_counters()
        super().check()

    def read(self) -> Batch:
        c = self.client
        if c is None:
            return self._spec.empty_batch()
        c.check()
        items = []
        while True:
            try:
                items.append(c.raw_frames.popleft())
            except IndexError:
                break
        batch = self.raw_to_batch(items, c) if items else None
        self._sync_counters()
        if batch is None or len(batch) == 0:
            if not self._fault_reported:
                try:
                    self.check()
                except DeviceFault:
                    self._fault_reported = True
                    raise
            return self._spec.empty_batch()
        self.counters.received += len(batch)
        return batch

    def raw_to_batch(self, items: list[tuple[int, bytes, nw.Version]], client: NatNetClient) -> Batch:
        """Undecoded frames (host ns, packet, version), in arrival order → one Batch; frames that do not decode
        are counted as parse errors and left out. Frames of a layout seen before are decoded together
        (:mod:`~beambench.devices.natnet.block`); the rest one at a time by the codec."""
        n = len(items)
        rows = self._empty_rows(n)
        host = rows[0]
        kept = np.zeros(n, dtype=bool)
        pending = np.arange(n)
        passes = 0
        while len(pending) and passes < 4:  # a layout per pass; ever-changing layouts end in the one-by-one loop
            first = int(pending[0])
            layout = self._layout(items[first][1], items[first][2])
            if layout is None:  # does not decode: counted (and left out) by the codec's path
                kept[first] = self._decode_one(rows, first, items[first], client)
                pending = pending[1:]
                continue
            passes += 1
            group = [i for i in pending if items[i][2] == layout.version]
            block, matches = nb.decode_block([items[i][1] for i in group], layout)
            done = np.asarray(group)[matches]
            self._fill_block(rows, done, block, client.clock_frequency)
            kept[done] = True
            pending = pending[~np.isin(pending, done)]
        for k in pending.tolist():
            kept[k] = self._decode_one(rows, k, items[k], client)
        host[:] = [item[0] for item in items]
        host, dev, data, frame_no, occluded = (a[kept] for a in rows)
        client.account_frames(frame_no.tolist())
        return Batch(self.name, host, dev, {"data": data, "frame": frame_no, "occluded": occluded})

    def _decode_one(
        self, rows: tuple[np.ndarray, ...], i: int, item: tuple[int, bytes, nw.Version], client: NatNetClient
    ) -> bool:
        """Row ``i`` from one packet through the codec; False (and a parse error counted) if it does not decode."""
        try:
            frame = nn.decode(item[1], item[2])
        except nw.NatNetParseError as exc:
            client.stats.parse_errors += 1
            client.stats.last_error = str(exc)
            return False
        if not isinstance(frame, nf.FrameOfData):  # pragma: no cover - only frame packets are kept raw
            return False
        self._fill_frame(rows, i, frame, client.clock_frequency)
        return True

    def _layout(self, packet: bytes, version: nw.Version) -> nb.FrameLayout | None:
        """The layout of ``packet``: the one cached for its length if its structure matches, else learned."""
        key = (len(packet), version)
        layout = self._layouts.get(key)
        if layout is not None and layout.fits(packet):
            return layout
        try:
            layout = nb.frame_layout(packet, version)
        except nw.NatNetParseError:
            return None
        if len(self._layouts) >= 64:
            self._layouts.clear()
        self._layouts[key] = layout
        return layout

    def _empty_rows(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Empty rows for ``n`` frames: host ns, device time, positions (NaN), frame numbers, occluded (True)."""
        m = len(self.markers)
        return (
            np.empty(n, dtype=np.int64),
            np.empty(n, dtype=np.float64),
            np.full((n, m, 3), np.nan),
            np.empty(n, dtype=np.int64),
            np.ones((n, m), dtype=bool),
        )

    def _fill_block(
        self, rows: tuple[np.ndarray, ...], at: np.ndarray, block: nb.FrameBlock, clock_frequency: int | None
    ) -> None:
        """Rows ``at`` from a block of frames decoded together (the same rules as :meth:`_fill_frame`)."""
        _, dev, data, frame, occluded = rows
        frame[at] = block.frame_number
        mid, ts = block.suffix["mid_exposure"].tolist(), block.suffix["timestamp"].tolist()
        dev[at] = [self._device_time(m, t, clock_frequency) for m, t in zip(mid, ts, strict=True)]
        for records, cols_by_id, flag_is_valid in (
            (block.labeled_markers, self._marker_cols, False),  # params bit 0: occluded
            (block.rigid_bodies, self._body_cols, True),  # params bit 0: tracking valid
        ):
            if not cols_by_id or records.shape[1] == 0:
                continue
            valid = (records["params"] & 0x01) != 0 if flag_is_valid else (records["params"] & 0x01) == 0
            for source_id, cols in cols_by_id.items():
                match = (records["id"] == source_id) & valid
                has = match.any(axis=1)
                if not has.any():
                    continue
                last = match.shape[1] - 1 - np.argmax(match[:, ::-1], axis=1)  # the frame's last entry wins
                pos = records["position"][np.arange(len(records)), last][has]
                for j in cols:
                    data[at[has], j] = pos
                    occluded[at[has], j] = False

    def _device_time(self, mid_exposure: int, timestamp: float, clock_frequency: int | None) -> float:
        """A frame's device time: mid-exposure ticks / the QPC rate when that mode is on and both are known (Python
        int division: exact), else Motive's timestamp."""
        if self.device_time_mode == "mid_exposure" and clock_frequency and mid_exposure:
            return mid_exposure / clock_frequency
        return timestamp

    def _fill_frame(self, rows: tuple[np.ndarray, ...], i: int, f: nf.FrameOfData, clock_frequency: int | None) -> None:
        """Row ``i`` from one decoded frame."""
        _, dev, data, frame, occluded = rows
        frame[i] = f.frame_number
        dev[i] = self._device_time(f.mid_exposure, f.timestamp, clock_frequency)
        for lm in f.labeled_markers:  # one pass over what the frame holds (not a lookup per marker name)
            cols = self._marker_cols.get(lm.id)
            if cols is not None and not lm.params & 0x01:  # bit 0: occluded
                data[i, cols] = lm.position
                occluded[i, cols] = False
        if self._body_cols:
            for rb in f.rigid_bodies:
                cols = self._body_cols.get(rb.id)
                if cols is not None and rb.tracking_valid:
                    data[i, cols] = rb.position
                    occluded[i, cols] = False

    def to_batch(self, items: list[tuple[int, nf.FrameOfData]], clock_frequency: int | None) -> Batch:
        """Decoded frames (host ns, frame) → one Batch of the mocap stream."""
        if not items:
            return self._spec.empty_batch()
        rows = self._empty_rows(len(items))
        for i, (host_ns, f) in enumerate(items):
            rows[0][i] = host_ns
            self._fill_frame(rows, i, f, clock_frequency)
        host, dev, data, frame, occluded = rows
        return Batch(self.name, host, dev, {"data": data, "frame": frame, "occluded": occluded})
