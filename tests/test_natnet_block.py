"""Frames decoded many at a time (devices.natnet.block) against the codec one at a time: the same values, bit for bit;
frames of another layout are left to the codec, never misread; the mocap stream is the same either way."""

from __future__ import annotations

import random

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from beambench.devices.natnet import block as nb
from beambench.devices.natnet import frame as nf
from beambench.devices.natnet import protocol as nn
from beambench.devices.natnet import wire as nw
from beambench.devices.natnet.client import NatNetClient
from beambench.devices.natnet.mocap import NatNetMocap
from beambench.devices.natnet.pcap import read_udp
from conftest import fuzz_examples, require_shared

MARKERS = ("base", "tip", "body")
MAP = {"base": "1:1", "tip": "1:2", "body": "rb:7"}


def make_frame(k: int, rng: random.Random, n_markers: int = 4, set_name: str = "beam") -> nf.FrameOfData:
    """A frame with every section the codec knows filled, and values that change with ``k``."""

    def v3() -> tuple[float, float, float]:
        return (rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(0, 2))

    def rb(i: int) -> nf.RigidBody:
        return nf.RigidBody(i, v3(), (0.0, 0.0, 0.0, 1.0), rng.uniform(0, 1e-3), rng.choice((0, 1)))

    lms = tuple(
        nf.LabeledMarker((1 << 16) | (i + 1), v3(), 0.014, rng.choice((0x02, 0x03, 0x0A)), rng.uniform(0, 1e-4))
        for i in range(n_markers)
    )
    return nf.FrameOfData(
        frame_number=1000 + k,
        marker_sets=(nf.MarkerSetData(set_name, (v3(), v3())), nf.MarkerSetData("all", (v3(),))),
        other_markers=(v3(),),
        rigid_bodies=(rb(7), rb(9)),
        skeletons=(nf.SkeletonData(3, (rb(1),)),),
        labeled_markers=lms,
        force_plates=(nf.AnalogData(1, ((1.0, 2.0), (3.0, 4.0))),),
        timecode=k,
        timestamp=1.0 + k / 360,
        mid_exposure=10_000_000 + 27_778 * k,
        data_received=10_000_100 + 27_778 * k,
        transmit=10_000_200 + 27_778 * k,
        precision_seconds=5,
        precision_fraction=k,
        params=0,
    )


def packets(version: nw.Version, n: int = 20, seed: int = 0, **kw) -> list[bytes]:  # type: ignore[no-untyped-def]
    rng = random.Random(seed)
    return [nn.encode(make_frame(k, rng, **kw), version) for k in range(n)]


def _same_floats(block_values: np.ndarray, codec_values: list) -> None:
    """Equal value for value, a NaN where the codec has one (a damaged float32 can decode to NaN, and NaN == NaN
    is false in a list comparison, so a plain ``==`` failed on packets the block read exactly as the codec did)."""
    np.testing.assert_array_equal(np.asarray(block_values, dtype=float), np.asarray(codec_values, dtype=float))


def assert_block_equals_codec(block: nb.FrameBlock, pkts: list[bytes], version: nw.Version) -> None:
    frames = [nn.decode(p, version) for p in pkts]
    assert len(block) == len(frames)
    for i, f in enumerate(frames):
        assert isinstance(f, nf.FrameOfData)
        assert block.frame_number[i] == f.frame_number
        assert block.suffix["timestamp"][i] == f.timestamp
        assert block.suffix["mid_exposure"][i] == f.mid_exposure
        lm = block.labeled_markers[i]
        assert lm["id"].tolist() == [m.id for m in f.labeled_markers]
        assert lm["params"].tolist() == [m.params for m in f.labeled_markers]
        _same_floats(lm["position"], [list(m.position) for m in f.labeled_markers])
        _same_floats(lm["residual"], [m.residual for m in f.labeled_markers])
        rb = block.rigid_bodies[i]
        assert rb["id"].tolist() == [b.id for b in f.rigid_bodies]
        _same_floats(rb["position"], [list(b.position) for b in f.rigid_bodies])
        assert rb["params"].tolist() == [b.params for b in f.rigid_bodies]


@pytest.mark.parametrize("version", [nw.V3_0, nw.V4_0, nw.V4_1])
def test_a_block_has_the_codecs_values_in_every_version(version):
    pkts = packets(version)
    assert len({len(p) for p in pkts}) == 1  # one layout
    layout = nb.frame_layout(pkts[0], version)
    block, matches = nb.decode_block(pkts, layout)
    assert matches.all()
    assert_block_equals_codec(block, pkts, version)


def test_another_layout_is_left_to_the_codec():
    v = nw.V4_1
    base = packets(v, n=6)
    renamed = packets(v, n=3, seed=1, set_name="bean")  # same length, another name: another layout
    more = packets(v, n=3, seed=2, n_markers=5)  # another length
    mixed = [base[0], renamed[0], base[1], more[0], base[2], renamed[1]]
    layout = nb.frame_layout(base[0], v)
    block, matches = nb.decode_block(mixed, layout)
    assert matches.tolist() == [True, False, True, False, True, False]
    assert [layout.fits(p) for p in mixed] == matches.tolist()
    assert_block_equals_codec(block, [base[0], base[1], base[2]], v)


def test_the_real_motive_capture_decodes_the_same_in_blocks():
    capture = require_shared("fixtures", "natnet", "traffic.pcapng")
    frames = [g.payload for g in read_udp(capture, [1511]) if nn.peek_message_id(g.payload) == nw.MessageId.FRAMEOFDATA]
    assert len(frames) > 100
    by_length: dict[int, list[bytes]] = {}
    for p in frames:
        by_length.setdefault(len(p), []).append(p)
    decoded = 0
    for group in by_length.values():
        block, matches = nb.decode_block(group, nb.frame_layout(group[0], nw.V3_0))
        assert matches[0]
        assert_block_equals_codec(block, [p for p, m in zip(group, matches, strict=True) if m], nw.V3_0)
        decoded += len(block)
    assert decoded > 0.9 * len(frames)


@settings(max_examples=fuzz_examples(300), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@example(edits=[(4149, 127)])  # a rigid body's y made NaN, read as NaN by both (found by hypothesis)
@given(st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), min_size=1, max_size=4))
def test_a_damaged_packet_is_never_misread(edits):
    """Bytes changed anywhere: either the block reads the values the codec reads, or it leaves the packet to
    the codec (which may reject it); a packet the codec rejects is never taken."""
    v = nw.V4_1
    template = packets(v, n=1)[0]
    layout = nb.frame_layout(template, v)
    damaged = bytearray(template)
    for pos, value in edits:
        damaged[pos % len(damaged)] = value
    block, matches = nb.decode_block([bytes(damaged)], layout)
    assert layout.fits(bytes(damaged)) == matches[0]
    try:
        nn.decode(bytes(damaged), v)
    except nw.NatNetParseError:
        assert not matches[0]
        return
    if matches[0]:
        assert_block_equals_codec(block, [bytes(damaged)], v)


def test_the_mocap_stream_is_the_same_from_raw_frames_and_from_decoded_ones(monkeypatch):
    """Raw frames in several layouts, with a garbled one among them, in arrival order → the same Batch as the
    decoded frames give; the garbled one is counted and left out, frame gaps are counted as dropped. Several
    layouts are read as blocks (the blocks the codec's ``decode_block`` decoded are watched)."""
    decode_block = nb.decode_block
    blocks: list[tuple[nb.FrameLayout, int]] = []

    def watched(packets, layout):  # type: ignore[no-untyped-def]
        block, matches = decode_block(packets, layout)
        blocks.append((layout, int(np.count_nonzero(matches))))
        return block, matches

    monkeypatch.setattr(nb, "decode_block", watched)
    v = nw.V4_1
    rng = random.Random(3)
    frames = [make_frame(k, rng, n_markers=3 + (k // 7) % 2, set_name="beam" if k % 5 else "bean") for k in range(40)]
    frames = [f for f in frames if f.frame_number != 1010]  # one dropped frame
    pkts = [nn.encode(f, v) for f in frames]
    items = [(1_000 + i, p, v) for i, p in enumerate(pkts)]
    items.insert(9, (999_999, pkts[9][:-30], v))  # truncated: garbled
    items.insert(0, (999_998, pkts[0][:7], v))  # garbled, and first: the rest is still read in blocks
    client = NatNetClient()
    mocap = NatNetMocap(MARKERS, marker_map=MAP)
    raw = mocap.raw_to_batch(items, client)
    decoded = [(1_000 + i, nn.decode(p, v)) for i, p in enumerate(pkts)]
    reference = NatNetMocap(MARKERS, marker_map=MAP).to_batch(decoded, None)  # type: ignore[arg-type]
    assert len(raw) == len(frames) == 39
    assert raw.host_time_ns.tolist() == reference.host_time_ns.tolist()
    assert raw.device_time.tolist() == reference.device_time.tolist()
    for name in ("frame", "occluded"):
        assert raw.columns[name].tolist() == reference.columns[name].tolist()
    assert np.array_equal(raw.columns["data"], reference.columns["data"], equal_nan=True)
    assert (~raw.columns["occluded"]).sum() > 30 and raw.columns["occluded"].sum() > 5  # both kinds present
    assert client.stats.parse_errors == 2
    assert client.stats.dropped_frames == 1 and client.stats.out_of_order == 0
    assert client.stats.frames == 39
    layouts = {(layout.length, layout.spans) for layout, decoded in blocks if decoded >= 2}
    assert len(layouts) >= 2  # several layouts were read as blocks of frames


def test_device_time_from_mid_exposure_ticks_in_blocks():
    v = nw.V4_1
    pkts = packets(v, n=5)
    client = NatNetClient()
    batch = NatNetMocap(MARKERS, marker_map=MAP).raw_to_batch([(i, p, v) for i, p in enumerate(pkts)], client)
    assert client.clock_frequency is None  # no SERVERINFO: Motive's timestamp
    assert batch.device_time.tolist() == [1.0 + k / 360 for k in range(5)]
