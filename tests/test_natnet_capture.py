"""The capture decoder against a real Motive 2.1 capture and the official SDK sample client's printout of it.

``traffic.pcapng`` holds 518 frames (162734–163251); ``SampleClient_output.txt`` printed the first 251 of
them (162734–162984) before the client was stopped. Every printed field of those 251 frames is compared
with our decoding, formatted as the sample client formats it (``%.2f``); all 518 must decode cleanly.
"""

from __future__ import annotations

import re
import socket
import struct
from datetime import timedelta
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from beambench.cli import app
from beambench.devices.natnet import frame as nf
from beambench.devices.natnet import modeldef as nm
from beambench.devices.natnet import protocol as nn
from beambench.devices.natnet import wire as nw
from beambench.devices.natnet.capture import decode_capture, frames_table
from beambench.devices.natnet.pcap import CaptureError, read_udp
from conftest import fuzz_examples, require_shared, shared_path

FIXTURES = shared_path("fixtures", "natnet")
CAPTURE = FIXTURES / "traffic.pcapng"
PRINTOUT = FIXTURES / "SampleClient_output.txt"


@pytest.fixture(scope="module")
def decoded():
    return decode_capture(require_shared("fixtures", "natnet", CAPTURE.name))


def parse_printout(text: str) -> dict[int, dict]:
    """The sample client's per-frame blocks → {frame id: fields as printed}."""
    frames: dict[int, dict] = {}
    cur: dict | None = None
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if m := re.match(r"FrameID : (\d+)$", line):
            cur = {"other": [], "rb": [], "lm": []}
            frames[int(m.group(1))] = cur
        elif cur is None:
            continue
        elif m := re.match(r"Timestamp : (\S+)$", line):
            cur["timestamp"] = m.group(1)
        elif m := re.match(r"Software latency : (\S+) milliseconds", line):
            cur["software_latency"] = m.group(1)
        elif m := re.match(r"System latency : (\S+) milliseconds", line):
            cur["system_latency"] = m.group(1)
        elif m := re.match(r"Timecode : (\S+)$", line):
            cur["timecode"] = m.group(1)
        elif m := re.match(r"Other Markers \[Count=(\d+)\]", line):
            cur["n_other"] = int(m.group(1))
        elif m := re.match(r"Other Marker \d+ : (\S+)\t(\S+)\t(\S+)$", line):
            cur["other"].append(m.groups())
        elif m := re.match(r"Rigid Bodies \[Count=(\d+)\]", line):
            cur["n_rb"] = int(m.group(1))
        elif m := re.match(r"Rigid Body \[ID=(\d+)\s+Error=(\S+)\s+Valid=(\d)\]", line):
            values = lines[i + 2].split()
            cur["rb"].append((int(m.group(1)), m.group(2), int(m.group(3)), tuple(values)))
        elif m := re.match(r"Skeletons \[Count=(\d+)\]", line):
            cur["n_skel"] = int(m.group(1))
        elif m := re.match(r"Labeled Markers \[Count=(\d+)\]", line):
            cur["n_lm"] = int(m.group(1))
        elif m := re.match(
            r"Labeled Marker \[ModelID=(\d+), MarkerID=(\d+), Occluded=(\d), PCSolved=(\d), ModelSolved=(\d)\] "
            r"\[size=(\S+)\] \[pos=(\S+),(\S+),(\S+)\]",
            line,
        ):
            g = m.groups()
            cur["lm"].append((int(g[0]), int(g[1]), int(g[2]), int(g[3]), int(g[4]), g[5], g[6:]))
        elif m := re.match(r"Force Plate \[Count=(\d+)\]", line):
            cur["n_fp"] = int(m.group(1))
        elif m := re.match(r"Device \[Count=(\d+)\]", line):
            cur["n_dev"] = int(m.group(1))
    return frames


def f2(x: float) -> str:
    """``printf("%.2f")`` as the MSVC-built sample client does it: the value is first rounded to 17 significant
    digits, then half away from zero (so 1356.175, stored as 1356.17499999999995…, prints as 1356.18)."""
    return str(Decimal(f"{x:.16e}").quantize(Decimal("0.01"), rounding=ROUND_HALF_UP))


def test_all_518_frames_decode_in_order(decoded):
    assert len(decoded.frames) == 518
    numbers = [f.frame_number for _, f in decoded.frames]
    assert numbers == list(range(162734, 162734 + 518))
    assert (decoded.parse_errors, decoded.dropped_frames, decoded.out_of_order) == (0, 0, 0)
    assert decoded.version == nw.V3_0 and decoded.version_source == "SERVERINFO"
    assert decoded.server_info.app_name == "Motive" and decoded.server_info.clock_frequency > 0
    assert decoded.frame_rate_hz == pytest.approx(120.0, rel=1e-6)  # the capture's FrameRate answer is 120 Hz
    for _, f in decoded.frames:  # the same scene throughout: one valid rigid body, six labeled markers
        assert [rb.id for rb in f.rigid_bodies] == [2] and f.rigid_bodies[0].tracking_valid
        assert len(f.labeled_markers) == 6 and len(f.other_markers) == 5
        assert f.mid_exposure < f.data_received < f.transmit
        assert f.timestamp == pytest.approx(f.frame_number / 120.0, abs=1e-6)


def test_frames_match_the_sample_client_field_by_field(decoded):
    printed = parse_printout(require_shared("fixtures", "natnet", PRINTOUT.name).read_text())
    assert len(printed) == 251
    freq = decoded.server_info.clock_frequency
    ours = {f.frame_number: f for _, f in decoded.frames}
    compared = 0
    for number, p in printed.items():
        f = ours[number]
        assert p["timestamp"] == f2(f.timestamp), number
        assert p["software_latency"] == f2((f.transmit - f.data_received) * 1000 / freq), number
        assert p["system_latency"] == f2((f.transmit - f.mid_exposure) * 1000 / freq), number
        assert p["timecode"] == f.timecode_string
        assert p["n_other"] == len(f.other_markers)
        assert p["other"] == [tuple(f2(x) for x in m) for m in f.other_markers], number
        assert p["n_rb"] == len(f.rigid_bodies)
        assert p["rb"] == [
            (rb.id, f2(rb.error), int(rb.tracking_valid), tuple(f2(x) for x in (*rb.position, *rb.orientation)))
            for rb in f.rigid_bodies
        ], number
        assert p["n_skel"] == len(f.skeletons) == 0
        assert p["n_lm"] == len(f.labeled_markers)
        assert p["lm"] == [
            (
                m.model_id,
                m.marker_id,
                int(m.occluded),
                int(m.point_cloud_solved),
                int(m.model_solved),
                f2(m.size),
                tuple(f2(x) for x in m.position),
            )
            for m in f.labeled_markers
        ], number
        assert p["n_fp"] == len(f.force_plates) and p["n_dev"] == len(f.devices)
        compared += 1
    assert compared == 251


def test_capture_holds_the_handshake(decoded):
    msgs = [nn.decode(g.payload, (3, 0)) for g in read_udp(CAPTURE, [1510, 1511])]
    kinds = [type(m).__name__ for m in msgs]
    assert kinds.count("FrameOfData") == 518 and kinds.count("EchoResponse") == 9
    rate = next(m for m in msgs if isinstance(m, nn.Response) and len(m.payload_bytes) == 4)
    assert rate.as_float() == 120.0  # the "FrameRate" answer
    md = next(m for m in msgs if isinstance(m, nm.ModelDef))
    assert md.rigid_bodies()[0].name == "RaceQuad"
    first_frame = next(g.payload for g in read_udp(CAPTURE, [1511]) if nn.peek_message_id(g.payload) == 7)
    if (FIXTURES / "mocapframe_packet_v3.bin").is_file():
        assert first_frame == (FIXTURES / "mocapframe_packet_v3.bin").read_bytes()


def test_frames_table_has_one_row_per_frame(decoded):
    df = frames_table(decoded)
    assert len(df) == 518
    assert list(df["frame"]) == list(range(162734, 163252))
    assert {"rb2_x", "rb2_valid", "m2_1_x", "m2_1_occluded", "m0_50007_params", "mid_exposure_ticks"} <= set(df.columns)
    assert (df["m2_1_occluded"] == 0).all() and (df["rb2_valid"] == 1).all()
    assert df["precision_s"].isna().all()  # NatNet 3.0 has no precision timestamp
    assert df["system_latency_ms"].between(1, 20).all()


def test_cli_decode_writes_csv_and_summary(decoded, tmp_path):
    out = tmp_path / "frames.csv"
    res = CliRunner().invoke(app, ["natnet", "decode", str(CAPTURE), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "518 frames (162734–163251), 0 dropped" in res.output and "NatNet 3.0 (SERVERINFO" in res.output
    df = pd.read_csv(out)
    assert len(df) == 518 and df["frame"].iloc[-1] == 163251
    assert df["mid_exposure_ticks"].iloc[0] == decoded.frames[0][1].mid_exposure


def test_cli_errors_are_one_line_and_exit_2(tmp_path):
    runner = CliRunner()
    bad = tmp_path / "junk.pcapng"
    bad.write_bytes(b"not a capture at all")
    for args in (
        ["natnet", "decode", str(tmp_path / "missing.pcap")],
        ["natnet", "decode", str(bad)],
        ["natnet", "decode", str(bad), "--natnet-version", "x"],
        ["natnet", "decode", str(bad), "--ports", "a"],
    ):
        res = runner.invoke(app, args)
        assert res.exit_code == 2, (args, res.output)
        assert res.exception is None or isinstance(res.exception, SystemExit)
        assert "beambench: error:" in res.output and "Traceback" not in res.output
    res = runner.invoke(app, ["natnet", "decode", str(bad)])
    assert f"beambench: error: {bad}: not a pcap" in res.stderr  # the message names the file


# ------------------------------------------------------------------------- a pcap we write ourselves


def write_pcap(path: Path, datagrams: list[tuple[float, bytes, int, int]], mtu: int = 1500) -> None:
    """Classic pcap of Ethernet/IPv4/UDP, fragmenting datagrams larger than the MTU (as the kernel would)."""
    import dpkt

    with path.open("wb") as fh:
        w = dpkt.pcap.Writer(fh, linktype=dpkt.pcap.DLT_EN10MB)
        for ident, (ts, payload, sport, dport) in enumerate(datagrams):
            udp = bytes(dpkt.udp.UDP(sport=sport, dport=dport, data=payload, ulen=8 + len(payload)))
            step = (mtu - 20) // 8 * 8
            for off in range(0, len(udp), step):
                chunk = udp[off : off + step]
                more = off + step < len(udp)
                ip = dpkt.ip.IP(
                    src=socket.inet_aton("10.0.0.1"),
                    dst=socket.inet_aton("239.255.42.99"),
                    p=17,
                    id=ident & 0xFFFF,
                    mf=int(more),
                    offset=off,
                    data=chunk,
                )
                ip.len = 20 + len(chunk)
                eth = dpkt.ethernet.Ethernet(src=b"\x00" * 6, dst=b"\x01\x00\x5e\x7f\x2a\x63", type=0x0800, data=ip)
                w.writepkt(bytes(eth), ts=ts)


def test_pcap_with_fragments_and_no_serverinfo_needs_the_version(tmp_path):
    big = nf.FrameOfData(
        10,
        labeled_markers=tuple(
            nf.LabeledMarker((1 << 16) | i, (i * 0.01, 0.5, -0.25), 0.014, 2, 0.0) for i in range(200)
        ),
        timestamp=10 / 360,
        mid_exposure=100,
        data_received=200,
        transmit=300,
        precision_seconds=5,
        precision_fraction=7,
    )
    small = nf.FrameOfData(12, timestamp=12 / 360, mid_exposure=110, data_received=210, transmit=310)
    packets = [nn.encode(big, (4, 1)), nn.encode(small, (4, 1)), b"\x07\x00\x05\x00junk"]
    assert len(packets[0]) > 1500  # must be reassembled from IPv4 fragments
    path = tmp_path / "unicast.pcap"
    write_pcap(path, [(1.0 + i, p, 1511, 50000) for i, p in enumerate(packets)])
    with pytest.raises(ValueError, match="--natnet-version"):
        decode_capture(path)
    d = decode_capture(path, "4.1")
    assert d.version_source == "option" and d.version == nw.V4_1
    assert [f for _, f in d.frames] == [nn.decode(p, nw.V4_1) for p in packets[:2]]
    assert len(d.frames[0][1].labeled_markers) == 200
    assert (d.dropped_frames, d.parse_errors) == (1, 1)
    df = frames_table(d)
    assert df["precision_s"].tolist() == [5, 0] and df["m1_199_x"].iloc[0] == pytest.approx(1.99)
    assert pd.isna(df["m1_199_x"].iloc[1])


def test_not_a_capture_is_a_capture_error(tmp_path):
    p = tmp_path / "x.pcap"
    p.write_bytes(struct.pack("<I", 0xDEADBEEF) + b"\0" * 40)
    with pytest.raises(CaptureError):
        list(read_udp(p))


def _decode_within(path: Path, seconds: float = 20.0, **kw):
    """decode_capture in a thread, bounded: a hang is a failure, not a stuck test run."""
    import threading

    box: dict = {}

    def work() -> None:
        try:
            box["out"] = decode_capture(path, **kw)
        except BaseException as exc:
            box["exc"] = exc

    t = threading.Thread(target=work, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), f"decode_capture did not return within {seconds} s"
    if "exc" in box:
        raise box["exc"]
    return box["out"]


def _ip_fragment(ident: int, offset: int, more: bool, data: bytes) -> bytes:
    import dpkt

    ip = dpkt.ip.IP(
        src=socket.inet_aton("10.0.0.1"),
        dst=socket.inet_aton("239.255.42.99"),
        p=17,
        id=ident,
        mf=int(more),
        offset=offset,
        data=data,
    )
    ip.len = 20 + len(data)
    return bytes(dpkt.ethernet.Ethernet(src=b"\x00" * 6, dst=b"\x01\x00\x5e\x7f\x2a\x63", type=0x0800, data=ip))


def test_an_empty_first_fragment_does_not_hang_the_decoder(tmp_path):
    """An empty fragment at offset 0 (more fragments set) followed by the last fragment is dropped (it must not
    make the reassembly loop spin forever) and the good frames around it still decode."""
    import dpkt

    good = nn.encode(nf.FrameOfData(5, timestamp=5 / 360, mid_exposure=1, data_received=2, transmit=3), (4, 1))
    udp = bytes(dpkt.udp.UDP(sport=1511, dport=50000, data=good, ulen=8 + len(good)))
    path = tmp_path / "empty_fragment.pcap"
    with path.open("wb") as fh:
        w = dpkt.pcap.Writer(fh, linktype=dpkt.pcap.DLT_EN10MB)
        w.writepkt(_ip_fragment(7, 0, True, b""), ts=1.0)  # the empty first fragment
        w.writepkt(_ip_fragment(7, 8, False, udp[8:]), ts=1.1)  # its last fragment
        w.writepkt(_ip_fragment(8, 0, False, udp), ts=1.2)  # an ordinary datagram after them
    d = _decode_within(path, version="4.1")
    assert [f.frame_number for _, f in d.frames] == [5]


def test_ticks_above_2_63_fit_the_frame_table(tmp_path):
    """QPC tick fields are uint64 on the wire: a value above 2**63 reaches the table whole (not a TypeError)."""
    big = 2**63 + 12345
    frame = nf.FrameOfData(3, timestamp=0.01, mid_exposure=big, data_received=big + 1, transmit=2**64 - 1)
    path = tmp_path / "ticks.pcap"
    write_pcap(path, [(1.0, nn.encode(frame, (4, 1)), 1511, 50000)])
    d = _decode_within(path, version="4.1")
    df = frames_table(d)
    assert int(df["mid_exposure_ticks"].iloc[0]) == big
    assert int(df["transmit_ticks"].iloc[0]) == 2**64 - 1


# ------------------------------------------------------------------------- fuzz: the documented error, bounded

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

PCAP_FUZZ = settings(  # a time bound per example (a loop that never ends fails it); generous, not a speed test
    max_examples=fuzz_examples(150),
    deadline=timedelta(seconds=5),
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)


@PCAP_FUZZ
@given(st.binary(max_size=3000))
def test_fuzz_any_file_reads_or_raises_capture_error(tmp_path, blob):
    """read_udp's contract: datagrams, or CaptureError (a BeambenchError) for what is not a capture."""
    p = tmp_path / "fuzz.pcap"
    p.write_bytes(blob)
    try:
        grams = list(read_udp(p))
    except CaptureError:
        return
    assert all(isinstance(g.payload, bytes) for g in grams)


fragment = st.tuples(
    st.integers(0, 5),  # ip id: several datagrams interleaved
    st.integers(0, 64).map(lambda k: 8 * k),  # fragment offset, bytes
    st.booleans(),  # more fragments
    st.binary(max_size=64),
)


@PCAP_FUZZ
@given(st.lists(fragment, max_size=40), st.binary(max_size=200))
def test_fuzz_arbitrary_ipv4_fragments_terminate(tmp_path, frags, tail):
    """Any mix of fragments (empty, overlapping, duplicated, missing) ends; a valid packet after them is read."""
    import dpkt

    path = tmp_path / "frags.pcap"
    good = bytes(dpkt.udp.UDP(sport=1511, dport=50000, data=tail, ulen=8 + len(tail)))
    with path.open("wb") as fh:
        w = dpkt.pcap.Writer(fh, linktype=dpkt.pcap.DLT_EN10MB)
        for i, (ident, off, more, data) in enumerate(frags):
            w.writepkt(_ip_fragment(100 + ident, off, more, data), ts=1.0 + i * 1e-3)
        w.writepkt(_ip_fragment(999, 0, False, good), ts=2.0)
    grams = list(read_udp(path))
    assert grams and grams[-1].payload == tail
