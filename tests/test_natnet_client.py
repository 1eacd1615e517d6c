"""Our NatNet client against our emulated Motive over real UDP on 127.0.0.1, for NatNet 3.0, 4.0 and 4.1.

Unicast and multicast (on loopback, TTL 0) both run here. Injected frame drops and occlusions must be counted
exactly; garbage packets are counted and never stop the stream.
"""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from beambench.acquisition.capabilities import Stream
from beambench.acquisition.streams import MOCAP
from beambench.devices.natnet import frame as nf
from beambench.devices.natnet import protocol as nn
from beambench.devices.natnet import wire as nw
from beambench.devices.natnet.client import BITSTREAM_GRACE_NS, NatNetClient, NatNetConfig, NatNetError, ping
from beambench.devices.natnet.emulated_motive import EmulatorClock, MotiveEmulator
from beambench.devices.natnet.mocap import MarkerSource, NatNetMocap
from beambench.devices.receive_time import mono_minus_real_ns
from conftest import holds_for, pause, wait_until

MARKERS = ("stage", "tip", "foot")
VERSIONS = ("3.0", "4.0", "4.1")


def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def moving(t: float) -> np.ndarray:
    """Three markers on a 5 Hz, 2 mm oscillation: a known truth for every frame."""
    x = 0.002 * np.sin(2 * np.pi * 5.0 * t)
    return np.array([[x, 0.0, 0.01], [0.1 + x, 0.02, 0.05], [0.2, 0.04 + x, 0.0]])


def emulator(version: str, multicast: bool, **kw) -> MotiveEmulator:  # type: ignore[no-untyped-def]
    kw.setdefault("positions", moving)
    return MotiveEmulator(version=version, command_port=0, data_port=free_udp_port(), multicast=multicast, **kw)


def config_for(emu: MotiveEmulator, **kw) -> NatNetConfig:  # type: ignore[no-untyped-def]
    return NatNetConfig(server_address="127.0.0.1", command_port=emu.command_address[1], multicast=emu.multicast, **kw)


def collect(mocap: NatNetMocap, through_frame: int) -> list:
    """Read the mocap's batches (as the runner does) until one holds frame ``through_frame`` or a later one."""
    batches: list = []

    def read() -> bool:
        b = mocap.read()
        if len(b):
            batches.append(b)
        return bool(batches) and int(batches[-1].columns["frame"][-1]) >= through_frame

    wait_until(read, what=f"frame {through_frame}", interval_s=0.05)
    return batches


def concat(batches):  # type: ignore[no-untyped-def]
    from beambench.acquisition.batch import Batch

    return Batch.concat(batches)


@pytest.mark.parametrize("multicast", [False, True], ids=["unicast", "multicast"])
@pytest.mark.parametrize("version", VERSIONS)
def test_stream_counts_injected_drops_and_occlusions_exactly(version, multicast):
    first = 1  # the emulator exposes frame 1 when our CONNECT arrives; the handshake takes a few dozen frames
    drops = {first + k for k in (110, 111, 112, 150, 200)}
    occl = {first + 120: [1], first + 121: [0, 2], first + 160: [2], first + 210: [0, 1, 2]}
    clock = EmulatorClock(offset_s=123.0, drift_ppm=50.0, jitter_s=0.0002, latency_s=0.001)
    with emulator(version, multicast, drop=drops, occlude=occl, clock=clock) as emu:
        mocap = NatNetMocap(MARKERS, config_for(emu))
        assert isinstance(mocap, Stream) and mocap.name == MOCAP
        mocap.start()
        try:
            batches = collect(mocap, first + 230)
            stats = mocap.stats
            info = mocap.identity()
        finally:
            mocap.stop()
    b = concat(batches)
    frames = b.columns["frame"]
    lo, hi = int(frames[0]), int(frames[-1])
    assert lo < first + 100 < first + 220 < hi, f"batches cover frames {lo}..{hi}: too slow a machine?"
    expected_missing = sorted(n for n in drops if lo < n < hi)
    assert sorted(set(range(lo, hi + 1)) - set(frames.tolist())) == expected_missing
    assert stats.dropped_frames == sum(stats.first_frame_number < n < stats.last_frame_number for n in drops) == 5
    assert stats.parse_errors == 0 and stats.out_of_order == 0
    # occlusions: exactly the injected (frame, marker) pairs, NaN positions there
    occluded = {(int(f), j) for i, f in enumerate(frames) for j in range(3) if b.columns["occluded"][i, j]}
    injected = {(f, j) for f, js in occl.items() for j in js if lo <= f <= hi}
    assert occluded == injected and len(injected) == 7
    assert np.isnan(b.columns["data"][b.columns["occluded"]]).all()
    # positions are the truth at float32 precision; t = frame index / rate
    seen = ~b.columns["occluded"]
    truth = np.stack([moving((f - first) / 360.0) for f in frames])
    np.testing.assert_allclose(b.columns["data"][seen], truth[seen], atol=1e-7)
    # device time = mid-exposure ticks / QPC rate on the emulator's clock, which never runs after receipt
    host_s = b.host_time_ns * 1e-9
    exposure_host_s = (b.device_time - clock.offset_s) / (1 + clock.drift_ppm * 1e-6)
    assert (exposure_host_s < host_s).all()
    assert np.median(host_s - exposure_host_s) < 0.05
    np.testing.assert_allclose(np.diff(b.device_time), np.diff(frames) / 360.0 * (1 + 50e-6), atol=2e-7)
    assert info["natnet_version"] == f"{version}.0.0" and info["stream_version"] == version
    assert info["frame_rate_hz"] == 360.0 and info["app_name"] == "Motive"
    assert info["clock_frequency_hz"] == clock.frequency_hz


def test_garbage_packets_are_counted_and_never_stop_the_stream():
    with emulator("4.1", multicast=False) as emu:
        client = NatNetClient(config_for(emu)).connect()
        try:
            address = client.receive_address  # unicast frames come to the command socket
            assert address is not None and address[0] == "127.0.0.1"
            port = address[1]
            junk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            good = nn.encode(nf.FrameOfData(1, timestamp=1.0), nw.V4_1)
            garbage = [
                b"",
                b"\x07",
                b"\x07\x00\xff\xff",
                good[:-7],
                b"\x07\x00" + good[2:20],
                b"\xff\xff\x00\x00",
                b"\x05\x00\x04\x00\xff\xff\xff\x7f",
            ]
            before = client.stats.frames
            for g in garbage:
                junk.sendto(g, ("127.0.0.1", port))
            junk.close()
            wait_until(lambda: client.stats.forged == len(garbage) and client.stats.frames > before + 50, what="junk")
            client.check()
            # not from the server: dropped unread and counted as forged, never a parse error
            assert client.stats.forged == len(garbage) and client.stats.parse_errors == 0
            assert client.stats.frames > before + 50  # still streaming
            after = client.stats.frames
            wait_until(lambda: client.stats.frames > after, what="frames after the junk")  # the thread lives on
        finally:
            client.close()


def test_bitstream_version_can_be_requested_from_a_4_x_server():
    with emulator("4.1", multicast=False) as emu:
        cfg = config_for(emu, bitstream_version="3.0")
        with NatNetClient(cfg) as client:
            assert client.version == nw.V3_0 and emu.stream_version == nw.V3_0
            assert client.server_info.natnet_version == (4, 1, 0, 0)
            wait_until(lambda: client.stats.frames > 20, what="20 frames")  # 56 ms at 360 Hz
            assert client.stats.parse_errors == 0
        assert "Bitstream,3.0" in emu.requests


def test_a_frame_encoded_before_a_bitstream_change_is_still_read_after_it():
    """The server's stream thread may encode a frame in the old bitstream, then its command thread switches and
    replies, then the older frame goes out: just after the change such a frame is decoded in the old version (a
    parse error before). Later, only the new version counts."""
    frame = nf.FrameOfData(
        frame_number=99_999,
        marker_sets=(nf.MarkerSetData("beam", ((0.1, 0.2, 0.3), (0.4, 0.5, 0.6))),),
        labeled_markers=(nf.LabeledMarker(65537, (1.0, 2.0, 3.0), 0.015625, 2, 0.0),),
        timestamp=1.0,
    )
    old = nn.encode(frame, nw.V4_1)
    with pytest.raises(nw.NatNetParseError):
        nn.decode(old, nw.V3_0)  # the premise: in the new version this packet does not parse

    def old_ones() -> int:
        return sum(f.frame_number == 99_999 for _, f in list(client.frames))

    with emulator("4.1", multicast=False) as emu, NatNetClient(config_for(emu)) as client:
        client.keep_frames = True
        errors = client.stats.parse_errors
        client.set_bitstream_version("3.0")
        assert client.version == nw.V3_0
        assert emu.send_packet(old) == 1  # from the server's data port, after the change: as a late frame goes out
        wait_until(old_ones, what="the frame encoded before the change")
        assert client.stats.parse_errors == errors
        pause(BITSTREAM_GRACE_NS * 1e-9, "the grace after the change runs out")
        assert emu.send_packet(old) == 1
        wait_until(lambda: client.stats.parse_errors == errors + 1, what="the old frame refused after the grace")
        assert old_ones() == 1


@pytest.mark.parametrize("keep_raw", [False, True], ids=["decoded", "raw"])
def test_frames_in_the_new_bitstream_that_beat_the_reply_are_decoded_in_it(keep_raw):
    """A server may switch its stream before its reply to ``Bitstream`` goes out (here 80 ms before: ~29 frames
    at 360 Hz); those frames are in the requested version and must decode as such, not count as parse errors."""
    with emulator("4.1", multicast=False, reply_delay_s=0.08) as emu, NatNetClient(config_for(emu)) as client:
        client.keep_raw = keep_raw
        before = client.stats.frames
        wait_until(lambda: client.stats.frames + len(client.raw_frames) > before + 20, what="20 frames")
        client.set_bitstream_version("3.0")
        assert client.version == nw.V3_0 and emu.stream_version == nw.V3_0
        if keep_raw:
            wait_until(lambda: nw.V3_0 in {v for _, _, v in list(client.raw_frames)}, what="frames in 3.0")
        else:
            wait_until(lambda: client.stats.frames > before + 40, what="40 frames")
        client.check()
        assert client.stats.parse_errors == 0, client.stats.last_error
        if keep_raw:  # the raw frames carry the version each one is in: all decode
            raw = list(client.raw_frames)
            assert {v for _, _, v in raw} == {nw.V4_1, nw.V3_0}
            for _, packet, v in raw:
                assert isinstance(nn.decode(packet, v), nf.FrameOfData)
        else:
            assert client.stats.frames > before + 40


def test_bitstream_change_is_refused_by_a_3_0_server():
    with emulator("3.0", multicast=False) as emu, pytest.raises(NatNetError, match="cannot change"):
        NatNetClient(config_for(emu, bitstream_version="4.1")).connect()


def test_echo_round_trips_give_a_clock_offset_by_minimum_rtt():
    clock = EmulatorClock(offset_s=1e4, drift_ppm=0.0, latency_s=0.0)
    with emulator("4.0", multicast=False, clock=clock) as emu:
        cfg = config_for(emu, echo_interval_s=0.02, initial_echoes=10)
        with NatNetClient(cfg) as client:
            client.keep_frames = True
            wait_until(lambda: len(client.echoes) >= 15 and len(client.frames) > 50, what="15 echoes")  # ~0.4 s
            echoes = list(client.echoes)
            best = client.best_echo()
            table = client.echo_table()
            frames = list(client.frames)
    assert len(echoes) >= 15 and len(table["server_ticks"]) == len(echoes)
    assert best.rtt_ns == min(e.rtt_ns for e in echoes) and best.rtt_ns < 20e6
    for e in echoes:  # the server stamped each echo between our send and our receive
        server_host_s = e.server_ticks / clock.frequency_hz - clock.offset_s
        assert e.host_send_ns * 1e-9 - 1e-6 <= server_host_s <= e.host_recv_ns * 1e-9 + 1e-6
    # mid-exposure mapped to host time through the best echo lands just before the receive time
    lag = [(host_ns - client.server_ticks_to_host_ns(f.mid_exposure)) * 1e-9 for host_ns, f in frames]
    assert len(lag) > 50
    assert -0.002 < np.median(lag) < 0.05


def test_rigid_body_mapping_and_tracking_loss():
    occl = {330: [0, 1], 331: [2]}  # late enough for a slow handshake on a loaded machine
    with emulator("4.1", multicast=False, rigid_bodies={5: [0, 1, 2]}, occlude=occl) as emu:
        mocap = NatNetMocap(("body", "tip"), config_for(emu), marker_map={"body": "rb:5", "tip": "1:2"})
        mocap.start()
        try:
            b = concat(collect(mocap, 341))
            md = mocap.client.model_def
        finally:
            mocap.stop()
    assert [d.id for d in md.rigid_bodies()] == [5]
    assert md.rigid_bodies()[0].markers[1].name == "tip"  # 4.x rigid-body descriptions carry marker names
    frames = b.columns["frame"].tolist()
    assert frames[0] < 330, frames[0]
    i_two_hidden, i_one_hidden, i_later = frames.index(330), frames.index(331), frames.index(340)
    assert b.columns["occluded"][i_two_hidden].tolist() == [True, True]  # 2 of 3 rigid-body markers hidden: not tracked
    assert b.columns["occluded"][i_one_hidden].tolist() == [False, False]  # one hidden: still tracked; tip visible
    assert b.columns["occluded"].sum() == 2
    np.testing.assert_allclose(b.columns["data"][i_later, 0], moving(339 / 360).mean(axis=0), atol=1e-7)
    np.testing.assert_allclose(b.columns["data"][i_later, 1], moving(339 / 360)[1], atol=1e-7)


def test_unicast_server_keeps_clients_that_send_keepalives():
    with emulator("4.0", multicast=False, unicast_timeout_s=0.3) as emu:
        with NatNetClient(config_for(emu, keepalive_interval_s=0.1)) as client:
            n1 = wait_until(lambda: client.stats.frames, what="the first frame")
            holds_for(lambda: len(emu.clients) == 1, 0.6, "the server keeps the client")  # twice its timeout
            assert client.stats.frames > n1 + 80  # past the server's 0.3 s timeout, still fed
        wait_until(lambda: emu.clients == {}, what="DISCONNECT on close")


def test_ping_reports_the_server():
    with emulator("4.1", multicast=True) as emu:
        info = ping(config_for(emu))
    assert info["app_name"] == "Motive" and info["app_version"] == "3.1.0.0"
    assert info["natnet_version"] == "4.1.0.0" and info["frame_rate_hz"] == 360.0


def test_no_server_is_a_clear_error_quickly():
    port = free_udp_port()
    t = time.monotonic()
    with pytest.raises(NatNetError, match="no SERVERINFO"):
        NatNetClient(NatNetConfig(command_port=port, timeout_s=0.3)).connect()
    assert time.monotonic() - t < 2.0


def test_marker_sources_parse():
    assert MarkerSource.parse("2:3") == MarkerSource("marker", (2 << 16) | 3)
    assert MarkerSource.parse((1, 4)) == MarkerSource("marker", (1 << 16) | 4)
    assert MarkerSource.parse("rb:7") == MarkerSource("rigid_body", 7)
    assert MarkerSource.parse(65537) == MarkerSource("marker", 65537)
    with pytest.raises(ValueError):
        NatNetMocap(("a", "b"), marker_map={"a": "1:1"})
    with pytest.raises(ValueError):
        MarkerSource.parse("rb:x")


def test_timestamp_device_time_and_empty_reads():
    mocap = NatNetMocap(MARKERS, device_time="timestamp")
    assert len(mocap.read()) == 0 and mocap.describe().columns["data"].shape == (3, 3)
    f = nf.FrameOfData(
        720, timestamp=2.0, mid_exposure=5, labeled_markers=(nf.LabeledMarker(65537, (1.0, 2.0, 3.0), 0.01, 2, 0.0),)
    )
    b = mocap.to_batch([(123, f)], clock_frequency=10)
    assert b.device_time.tolist() == [2.0] and b.host_time_ns.tolist() == [123]
    assert b.columns["occluded"].tolist() == [[False, True, True]]
    b2 = NatNetMocap(MARKERS).to_batch([(1, f)], clock_frequency=10)
    assert b2.device_time.tolist() == [0.5]  # mid-exposure ticks / QPC rate


def test_from_rig_section():
    section = {
        "server_address": "10.0.0.5",
        "command_port": 1510,
        "multicast": False,
        "markers": {"stage": "1:1", "tip": "1:2", "foot": "rb:3"},
        "rate_hz": 240.0,
    }
    mocap = NatNetMocap.from_rig(section)
    assert mocap.markers == ("stage", "tip", "foot") and mocap.config.server_address == "10.0.0.5"
    assert mocap.sources[2] == MarkerSource("rigid_body", 3) and mocap.describe().rate_hz == 240.0
    with pytest.raises(ValueError, match="unknown NatNet setting"):
        NatNetMocap.from_rig({"server": "x", "markers": {"a": 1}})


def test_a_failing_position_source_stops_the_emulator_visibly():
    def broken(t: float) -> np.ndarray:
        return np.zeros((2, 3))  # wrong shape for three markers

    with (
        emulator("4.0", multicast=False, positions=lambda t: moving(t)) as emu,
        NatNetClient(config_for(emu)) as client,
    ):
        emu.set_positions(broken)
        wait_until(lambda: _stopped(emu), what="the emulator to stop")
        with pytest.raises(RuntimeError, match="shape"):
            emu.check()
        counts: list[int] = []  # the frames in flight when it stopped are read: 5 polls in a row with no new one
        wait_until(lambda: counts.append(client.stats.frames) or counts[-5:].count(counts[-1]) == 5, interval_s=0.03)
        n = client.stats.frames
        holds_for(lambda: client.stats.frames == n, 0.2, "nothing more arrives")


def _stopped(emu: MotiveEmulator) -> bool:
    try:
        emu.check()
    except RuntimeError:
        return True
    return False


@pytest.mark.parametrize("multicast", [False, True])
def test_each_frame_carries_the_kernels_receive_time_not_the_time_it_was_read(multicast):
    """The receive thread reads ~20 ms of frames per wake-up (less CPU); each frame's host time is still its
    own arrival (the kernel's stamp): after the emulator's send time (its clock is the host's here) and close to
    it, while the read comes up to 20 ms later."""
    seen: list[tuple[int, int, int]] = []  # (host stamp, read time, the server's transmit ticks)

    def on_frame(host_ns: int, f: nf.FrameOfData) -> None:
        seen.append((host_ns, time.monotonic_ns(), f.transmit))

    clock = EmulatorClock(offset_s=0.0, drift_ppm=0.0, latency_s=0.0)
    with emulator("4.1", multicast=multicast, clock=clock) as emu, NatNetClient(config_for(emu), on_frame=on_frame):
        wait_until(lambda: len(seen) >= 400, what="400 frames", interval_s=0.02)
    rows = np.array(seen[50:400], dtype=np.float64)
    assert len(rows) >= 300
    stamp_s, read_s, sent_s = rows[:, 0] * 1e-9, rows[:, 1] * 1e-9, rows[:, 2] / clock.frequency_hz
    assert np.all(stamp_s <= read_s)
    assert np.all(stamp_s >= sent_s - 1e-4)  # never before the server sent it (0.1 ms for clock reads)
    assert np.median(stamp_s - sent_s) < 0.004, np.median(stamp_s - sent_s)  # arrival: right after sending
    assert np.median(read_s - sent_s) > np.median(stamp_s - sent_s)  # the read itself comes later


def test_the_offset_between_the_wall_and_monotonic_clocks_is_read_tightly():
    """The offset moves kernel (wall-clock) receive stamps onto the monotonic clock: it must be the true offset
    (sign and size) and steady from read to read (a skewed read would move a stamp by the skew)."""
    naive = time.monotonic_ns() - time.time_ns()
    reads = [mono_minus_real_ns() for _ in range(2000)]
    assert abs(reads[0] - naive) < 5_000_000
    assert max(reads) - min(reads) < 200_000, (max(reads) - min(reads)) / 1e3


class _FrameBeforeServerInfo(MotiveEmulator):
    """A server whose frame thread reaches a new unicast client before the SERVERINFO reply does (the client is
    registered first, then answered: under load a frame slips in between)."""

    def _command(self, msg, addr, now_ticks):  # type: ignore[no-untyped-def]
        if isinstance(msg, nn.Connect) and not isinstance(msg, nn.Discovery) and self._data is not None:
            self._data.sendto(nn.encode(nf.FrameOfData(1, timestamp=0.0), self.stream_version), addr)
            pause(0.02, "the SERVERINFO reply comes 20 ms after the frame")
        super()._command(msg, addr, now_ticks)


def test_a_server_frame_that_beats_its_serverinfo_is_not_counted_as_forged():
    """Before SERVERINFO names the data port, a datagram from the server's address is early, not forged: the
    forged count stays exactly what came from other senders."""
    emu = _FrameBeforeServerInfo(
        version="4.1", command_port=0, data_port=free_udp_port(), multicast=False, positions=moving
    )
    with emu:
        client = NatNetClient(config_for(emu)).connect()
        try:
            wait_until(lambda: client.stats.frames >= 20, what="20 frames")
            assert client.stats.forged == 0, client.stats
            assert client.stats.ignored >= 1  # the early frame: read, and left out (no version yet)
        finally:
            client.close()
