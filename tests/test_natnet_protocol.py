"""NatNet codec: the independent v3 packets in ../shared/fixtures/natnet, round trips per version, and fuzzing."""

from __future__ import annotations

import contextlib
import math
import struct
from datetime import timedelta

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from beambench.devices.natnet import frame as nf
from beambench.devices.natnet import modeldef as nm
from beambench.devices.natnet import protocol as nn
from beambench.devices.natnet import wire as nw
from conftest import fuzz_examples, require_shared

V30, V40, V41 = nw.V3_0, nw.V4_0, nw.V4_1


def fixture(name: str) -> bytes:
    return require_shared("fixtures", "natnet", name).read_bytes()


# ------------------------------------------------------------------------------------------ real v3 packets


def test_connect_and_discovery_packets_decode_and_reencode_byte_exact():
    for name, kind in (("connect_packet_v3.bin", nn.Connect), ("discovery_packet_v3.bin", nn.Discovery)):
        raw = fixture(name)
        msg = nn.decode(raw)
        assert type(msg) is kind
        assert msg.sender == nn.Sender("NatNetLib", nw.Version(3, 0, 0, 0), nw.Version(3, 0, 0, 0))
        assert msg.bitstream_version is None
        assert nn.encode(msg) == raw


def test_serverinfo_packet():
    msg = nn.decode(fixture("serverinfo_packet_v3.bin"))
    assert isinstance(msg, nn.ServerInfo)
    assert (msg.app_name, msg.app_version, msg.natnet_version) == ("Motive", (2, 1, 0, 0), (3, 0, 0, 0))
    assert msg.clock_frequency == 3312787
    assert (msg.data_port, msg.multicast, msg.multicast_group) == (1511, True, "239.255.42.99")
    # Motive leaves stale bytes after the name's NUL; our encoding zero-fills, everything else is identical
    again = nn.decode(nn.encode(msg))
    assert again == msg


def test_echo_request_and_response():
    req = nn.decode(fixture("echorequest_packet_v3.bin"))
    resp = nn.decode(fixture("echoresponse_packet_v3.bin"))
    assert req == nn.EchoRequest(278554190)
    assert resp == nn.EchoResponse(278554190, 1416498545924)
    assert nn.encode(req) == fixture("echorequest_packet_v3.bin")
    assert nn.encode(resp) == fixture("echoresponse_packet_v3.bin")


def test_request_modeldef_and_modeldef():
    assert nn.decode(fixture("requestmodeldef_packet_v3.bin")) == nn.RequestModelDef()
    raw = fixture("modeldef_packet_v3.bin")
    md = nn.decode(raw, V30)
    assert isinstance(md, nm.ModelDef)
    rb, ms, all_ = md.datasets
    assert isinstance(rb, nm.RigidBodyDescription)
    assert (rb.name, rb.id, rb.parent_id, rb.offset, len(rb.markers)) == ("RaceQuad", 2, -1, (0.0, 0.0, 0.0), 5)
    assert rb.markers[0].offset == pytest.approx((0.16116, 0.03505, -0.03218), abs=1e-5)
    assert [m.active_label for m in rb.markers] == [0] * 5
    assert ms == nm.MarkerSetDescription("RaceQuad", ("Marker1", "Marker2", "Marker3", "Marker4", "Marker5"))
    assert all_.marker_names == tuple(f"RaceQuad_{i}" for i in range(1, 6))
    assert nn.encode(md, V30) == raw


def test_mocap_frame_packet():
    raw = fixture("mocapframe_packet_v3.bin")
    f = nn.decode(raw, V30)
    assert isinstance(f, nf.FrameOfData)
    assert f.frame_number == 162734
    assert f.marker_sets == ()
    assert len(f.other_markers) == 5
    assert f.other_markers[0] == pytest.approx((0.1272162, 1.5050275, -0.8858284))
    (rb,) = f.rigid_bodies
    assert rb.id == 2 and rb.tracking_valid
    assert rb.position == pytest.approx((0.174447, 1.447131, -0.734304), abs=1e-6)
    assert rb.orientation == pytest.approx((-0.054594, 0.509948, 0.043704, -0.857358), abs=1e-6)
    assert [(m.model_id, m.marker_id) for m in f.labeled_markers] == [
        (2, 1),
        (2, 2),
        (2, 3),
        (2, 4),
        (2, 5),
        (0, 50007),
    ]
    assert not any(m.occluded for m in f.labeled_markers)
    assert all(m.point_cloud_solved for m in f.labeled_markers)
    assert f.labeled_markers[-1].unlabeled
    assert f.timestamp == pytest.approx(162734 / 120)
    assert (f.mid_exposure, f.data_received, f.transmit) == (1416497730518, 1416497745808, 1416497748722)
    assert f.precision_seconds is None and f.timecode_string == "00:00:00:00.0"
    assert nn.encode(f, V30) == raw


def test_mocap_frame_with_an_occluded_marker():
    raw = fixture("mocapframe_packet_occluded_v3.bin")
    f = nn.decode(raw, V30)
    assert f.frame_number == 269007
    assert [ms.name for ms in f.marker_sets] == ["FakeTree", "all"]
    assert [(m.model_id, m.marker_id, m.occluded) for m in f.labeled_markers] == [
        (7, 2, True),
        (7, 3, False),
        (7, 4, False),
        (7, 5, False),
    ]
    assert f.labeled_markers[0].model_solved is False and f.labeled_markers[0].has_model
    assert f.rigid_bodies[0].id == 7 and f.rigid_bodies[0].tracking_valid
    assert nn.encode(f, V30) == raw


def test_frame_needs_a_version_and_wrong_version_is_a_parse_error():
    raw = fixture("mocapframe_packet_v3.bin")
    with pytest.raises(nw.NatNetParseError, match="version"):
        nn.decode(raw)
    with pytest.raises(nw.NatNetParseError):
        nn.decode(raw, V41)  # 4.1 expects section sizes: the v3 bytes cannot parse as 4.1
    with pytest.raises(nw.NatNetParseError, match="unsupported"):
        nn.decode(raw, nw.Version(2, 9))


def test_every_truncation_of_the_real_packets_raises_the_parse_error_only():
    for name in (
        "mocapframe_packet_v3.bin",
        "mocapframe_packet_occluded_v3.bin",
        "modeldef_packet_v3.bin",
        "serverinfo_packet_v3.bin",
        "echoresponse_packet_v3.bin",
        "connect_packet_v3.bin",
    ):
        raw = fixture(name)
        decoded = []
        for n in range(len(raw)):
            cut = raw[:n]
            cut = cut[:2] + struct.pack("<H", max(0, n - 4)) + cut[4:] if n >= 4 else cut  # consistent header
            try:
                nn.decode(cut, V30)
            except nw.NatNetParseError:
                continue
            decoded.append(n)
        # the one cut that is itself a valid message: a connect of the client's name alone ("NatNetLib\0"), the
        # short form older clients send
        name_only = [raw.index(b"\0", 4) + 1] if name == "connect_packet_v3.bin" else []
        assert decoded == name_only, (name, decoded)


# ------------------------------------------------------------------------------------------ round trips

f32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
vec3 = st.tuples(f32, f32, f32)
quat = st.tuples(f32, f32, f32, f32)
i32 = st.integers(-(2**31), 2**31 - 1)
u64 = st.integers(0, 2**64 - 1)
u32 = st.integers(0, 2**32 - 1)
i16 = st.integers(-(2**15), 2**15 - 1)
name = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\0"), max_size=12)
rigid_body = st.builds(nf.RigidBody, i32, vec3, quat, f32, i16)
labeled = st.builds(nf.LabeledMarker, i32, vec3, f32, i16, f32)
analog = st.builds(nf.AnalogData, i32, st.lists(st.lists(f32, max_size=3).map(tuple), max_size=3).map(tuple))
asset = st.builds(
    nf.AssetData,
    i32,
    st.lists(rigid_body, max_size=2).map(tuple),
    st.lists(st.builds(nf.AssetMarker, i32, vec3, f32, i16, f32), max_size=2).map(tuple),
)
frames = st.builds(
    nf.FrameOfData,
    frame_number=i32,
    marker_sets=st.lists(st.builds(nf.MarkerSetData, name, st.lists(vec3, max_size=3).map(tuple)), max_size=2).map(
        tuple
    ),
    other_markers=st.lists(vec3, max_size=3).map(tuple),
    rigid_bodies=st.lists(rigid_body, max_size=3).map(tuple),
    skeletons=st.lists(st.builds(nf.SkeletonData, i32, st.lists(rigid_body, max_size=2).map(tuple)), max_size=2).map(
        tuple
    ),
    assets=st.lists(asset, max_size=2).map(tuple),
    labeled_markers=st.lists(labeled, max_size=5).map(tuple),
    force_plates=st.lists(analog, max_size=2).map(tuple),
    devices=st.lists(analog, max_size=2).map(tuple),
    timecode=u32,
    timecode_sub=u32,
    timestamp=st.floats(allow_nan=False),
    mid_exposure=u64,
    data_received=u64,
    transmit=u64,
    precision_seconds=u32,
    precision_fraction=u32,
    params=i16,
)


def as_sent(frame: nf.FrameOfData, v: nw.Version) -> nf.FrameOfData:
    """What a frame looks like after a trip through version ``v`` (fields that version lacks drop out)."""
    if v >= V41:
        return frame
    from dataclasses import replace

    return replace(frame, assets=(), precision_seconds=None, precision_fraction=None)


@settings(max_examples=fuzz_examples(100), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(frames, st.sampled_from([V30, V40, V41]))
def test_frames_round_trip_in_every_version(frame, v):
    packet = nn.encode(frame, v)
    back = nn.decode(packet, v)
    assert back == as_sent(frame, v)
    assert nn.encode(back, v) == packet
    if v >= V41:
        assert back.section_sizes is not None and len(back.section_sizes) == 8
    else:
        assert back.section_sizes is None


rb_desc = st.builds(
    nm.RigidBodyDescription,
    name,
    i32,
    i32,
    vec3,
    st.lists(st.builds(nm.RigidBodyMarker, vec3, i32, name), max_size=3).map(tuple),
)
descriptions = st.one_of(
    st.builds(nm.MarkerSetDescription, name, st.lists(name, max_size=4).map(tuple)),
    rb_desc,
    st.builds(nm.SkeletonDescription, name, i32, st.lists(rb_desc, max_size=2).map(tuple)),
    st.builds(
        nm.ForcePlateDescription,
        i32,
        name,
        f32,
        f32,
        vec3,
        st.lists(st.lists(f32, min_size=12, max_size=12).map(tuple), min_size=12, max_size=12).map(tuple),
        st.lists(vec3, min_size=4, max_size=4).map(tuple),
        i32,
        i32,
        st.lists(name, max_size=3).map(tuple),
    ),
    st.builds(nm.DeviceDescription, i32, name, name, i32, i32, st.lists(name, max_size=3).map(tuple)),
    st.builds(nm.CameraDescription, name, vec3, quat),
    st.builds(
        nm.AssetDescription,
        name,
        i32,
        i32,
        st.lists(rb_desc, max_size=2).map(tuple),
        st.lists(st.builds(nm.MarkerDescription, name, i32, vec3, f32, i16), max_size=2).map(tuple),
    ),
)


def desc_as_sent(d, v: nw.Version):  # type: ignore[no-untyped-def]
    """Rigid-body marker names exist from 4.0 on."""
    from dataclasses import replace

    if v >= V40:
        return d
    if isinstance(d, nm.RigidBodyDescription):
        return replace(d, markers=tuple(replace(m, name="") for m in d.markers))
    if isinstance(d, (nm.SkeletonDescription, nm.AssetDescription)):
        return replace(d, rigid_bodies=tuple(desc_as_sent(r, v) for r in d.rigid_bodies))
    return d


@settings(max_examples=fuzz_examples(100), deadline=None)
@given(st.lists(descriptions, max_size=4), st.sampled_from([V30, V40, V41]))
def test_modeldef_round_trips_in_every_version(datasets, v):
    md = nm.ModelDef(tuple(datasets))
    back = nn.decode(nn.encode(md, v), v)
    assert back == nm.ModelDef(tuple(desc_as_sent(d, v) for d in datasets))


def test_simple_messages_round_trip():
    sender = nn.Sender("beambench", nw.Version(0, 1), nw.Version(4, 1))
    for msg in [
        nn.Connect(sender),
        nn.Connect(sender, False, nw.Version(4, 0)),
        nn.Discovery(sender),
        nn.ServerInfo(
            nn.Sender("Motive", nw.Version(3, 1), nw.Version(4, 1)), 10_000_000, 1511, False, "239.255.42.99"
        ),
        nn.Request("FrameRate"),
        nn.Response.of_float(360.0),
        nn.Response.of_int(-1),
        nn.Response.of_text("Bitstream,4.1"),
        nn.RequestModelDef(),
        nn.RequestFrameOfData(),
        nn.MessageString("hello"),
        nn.Disconnect(),
        nn.KeepAlive(),
        nn.DisconnectByTimeout(),
        nn.EchoRequest(2**63 + 5),
        nn.EchoResponse(1, 2**40),
        nn.UnrecognizedRequest(b"x"),
    ]:
        assert nn.decode(nn.encode(msg, V41), V41) == msg, msg
    assert nn.decode(nn.encode(nn.Response.of_float(360.0))).as_float() == 360.0
    assert nn.decode(nn.encode(nn.Response.of_text("Bitstream,4.1"))).as_text() == "Bitstream,4.1"
    with pytest.raises(nw.NatNetParseError):
        nn.Response.of_text("long text").as_int()


def test_4_1_sections_skip_newer_fields_but_reject_overruns():
    frame = nf.FrameOfData(
        7, labeled_markers=(nf.LabeledMarker(65537, (1.0, 2.0, 3.0), 0.015625, 2, 0.0),), timestamp=1.0
    )
    packet = bytearray(nn.encode(frame, V41))
    # labeled markers: header(4) + frame number(4) + 5 empty sections (count, size) before it
    at = 4 + 4 + 5 * 8
    assert struct.unpack_from("<ii", packet, at) == (1, 26)
    grown = (
        packet[: at + 4] + struct.pack("<i", 30) + packet[at + 8 : at + 8 + 26] + b"\xaa" * 4 + packet[at + 8 + 26 :]
    )
    grown[2:4] = struct.pack("<H", len(grown) - 4)
    assert nn.decode(bytes(grown), V41).labeled_markers == frame.labeled_markers  # unknown trailing field skipped
    shrunk = bytearray(packet)
    struct.pack_into("<i", shrunk, at + 4, 20)
    with pytest.raises(nw.NatNetParseError, match="overran"):
        nn.decode(bytes(shrunk), V41)


def test_version_parse():
    assert nw.Version.parse("4.1") == (4, 1, 0, 0)
    assert str(nw.Version.parse("3.0.0.0")) == "3.0.0.0"
    for bad in ("", "x", "1.2.3.4.5", "300.1"):
        with pytest.raises(ValueError):
            nw.Version.parse(bad)


# ------------------------------------------------------------------------------------------ fuzz

# a time bound per example: a decoder that loops or blows up on a bad length fails it (a generous one: this is
# not a speed test, speed is in benchmarks/)
BOUND = timedelta(seconds=5)
VERSIONS = st.sampled_from([None, V30, V40, V41, nw.Version(4, 2), nw.Version(2, 9), nw.Version(5, 0)])


def check_only_parse_error(packet: bytes, version) -> None:  # type: ignore[no-untyped-def]
    with contextlib.suppress(nw.NatNetParseError):
        nn.decode(packet, version)


@settings(max_examples=fuzz_examples(1500), deadline=BOUND)
@given(st.binary(max_size=600), VERSIONS)
def test_fuzz_random_bytes(packet, version):
    check_only_parse_error(packet, version)


@settings(max_examples=fuzz_examples(1500), deadline=BOUND)
@given(st.sampled_from(list(nw.MessageId)), st.binary(max_size=400), VERSIONS)
def test_fuzz_every_message_id_with_random_payload(msg_id, payload, version):
    check_only_parse_error(struct.pack("<HH", msg_id, len(payload)) + payload, version)


@settings(max_examples=fuzz_examples(150), deadline=BOUND, suppress_health_check=[HealthCheck.too_slow])
@given(frames, st.sampled_from([V30, V40, V41]), st.data())
def test_fuzz_mutated_valid_frames(frame, v, data):
    packet = bytearray(nn.encode(frame, v))
    for _ in range(data.draw(st.integers(1, 6))):
        i = data.draw(st.integers(0, len(packet) - 1))
        packet[i] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(packet)))
    check_only_parse_error(bytes(packet[:cut]), data.draw(st.sampled_from([V30, V40, V41])))
    check_only_parse_error(bytes(packet), v)


@settings(max_examples=fuzz_examples(120), deadline=BOUND)
@given(st.lists(descriptions, max_size=3), st.sampled_from([V30, V40, V41]), st.data())
def test_fuzz_mutated_modeldefs(datasets, v, data):
    packet = bytearray(nn.encode(nm.ModelDef(tuple(datasets)), v))
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(packet) - 1))
        packet[i] = data.draw(st.integers(0, 255))
    check_only_parse_error(bytes(packet), v)


def test_nan_and_inf_floats_decode_without_error():
    frame = nf.FrameOfData(1, other_markers=((math.nan, math.inf, -math.inf),), timestamp=math.nan)
    back = nn.decode(nn.encode(frame, V40), V40)
    assert math.isnan(back.other_markers[0][0]) and math.isinf(back.other_markers[0][1])
