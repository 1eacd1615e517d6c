"""Load-cell frame layout, CRC variant, single-frame decoding and the resynchronising stream decoder."""

import random
import struct

import pytest

from beambench.devices.loadcell.protocol import (
    FRAME_LEN,
    SYNC,
    LoadCellParseError,
    StreamDecoder,
    crc16,
    decode_frame,
    encode_frame,
)


def frames(n, start=0):
    return [encode_frame(k, 1000 * k, (k, -k, 7 * k, 2**31 - 1 - k), k // 3) for k in range(start, start + n)]


def accounted(d: StreamDecoder) -> int:
    s = d.stats
    return FRAME_LEN * s.frames + s.unsupported_bytes + s.bytes_discarded + s.startup_bytes + d.pending


def test_crc_is_ccitt_false():
    assert crc16(b"123456789") == 0x29B1  # the catalogue check value of CRC-16/CCITT-FALSE (IBM-3740)
    crccheck = pytest.importorskip("crccheck.crc", reason="crccheck (a cantools dependency) not installed")
    rnd = random.Random(3)
    for n in (0, 1, 30, 257):
        data = rnd.randbytes(n)
        assert crc16(data) == crccheck.Crc16CcittFalse.calc(data)


def test_frame_layout_field_by_field():
    f = encode_frame(0x01020304, 0xA0B0C0D0, (-1, 2, -(2**31), 2**31 - 1), 77)
    assert len(f) == FRAME_LEN == 34
    assert f[:2] == b"\xa5\x5a" and f[2] == 29 and f[3] == 1
    assert f[4:8] == bytes([4, 3, 2, 1])  # little-endian seq
    assert int.from_bytes(f[8:12], "little") == 0xA0B0C0D0
    assert [int.from_bytes(f[12 + 4 * i : 16 + 4 * i], "little", signed=True) for i in range(4)] == [
        -1,
        2,
        -(2**31),
        2**31 - 1,
    ]
    assert int.from_bytes(f[28:32], "little") == 77
    assert int.from_bytes(f[32:34], "little") == crc16(f[2:32])


def test_roundtrip_and_32_bit_wrap_of_counters():
    f = decode_frame(encode_frame(2**32 + 5, -1, (0, 0, 0, 0), 2**32))
    assert (f.version, f.seq, f.t_us, f.sync_edges) == (1, 5, 2**32 - 1, 0)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda f: f[:3], "too short"),
        (lambda f: b"\x5a\xa5" + f[2:], "sync"),
        (lambda f: f + b"\x00", "length byte"),
        (lambda f: f[:20] + bytes([f[20] ^ 0x10]) + f[21:], "CRC-16/CCITT-FALSE mismatch"),
    ],
)
def test_decode_frame_names_the_problem(mutate, message):
    with pytest.raises(LoadCellParseError, match=message):
        decode_frame(mutate(encode_frame(1, 2, (3, 4, 5, 6), 7)))


def test_unknown_version_with_valid_crc_is_unsupported():
    body = bytes([5, 2, 9, 9, 9, 9])  # length 5, version 2
    frame = SYNC + body + struct.pack("<H", crc16(body))
    with pytest.raises(LoadCellParseError, match="unsupported frame version 2"):
        decode_frame(frame)
    good = frames(4)
    d = StreamDecoder()
    out = d.feed(good[0] + good[1] + frame + good[2] + good[3])
    assert [f.seq for f in out] == [0, 1, 2, 3]
    assert d.stats.unsupported == 1 and d.stats.crc_errors == 0 and d.stats.lost_frames == 0
    assert d.stats.last_version == 1
    assert accounted(d) == d.stats.bytes_in


def test_resync_after_garbage_and_startup_bytes_not_counted_as_errors():
    fs = frames(20)
    garbage = bytes(random.Random(1).randbytes(500)) + b"\xa5\x5a\x1d\x01\x02"  # ends in a false header
    d = StreamDecoder()
    out = d.feed(fs[0][10:] + garbage + b"".join(fs))  # opened mid-frame, then noise
    assert [f.seq for f in out] == list(range(20))
    assert d.stats.startup_bytes == 24 + len(garbage)
    assert d.stats.crc_errors == d.stats.truncated == d.stats.bytes_discarded == 0
    assert accounted(d) == d.stats.bytes_in


def test_crc_error_and_truncation_are_told_apart_and_frames_lost_counted():
    fs = [bytearray(f) for f in frames(12)]
    fs[3][20] ^= 0x04  # corrupted: CRC error
    del fs[6][9:11]  # two bytes lost: truncated
    fs[9] = bytearray(random.Random(2).randbytes(7))  # frame 9 replaced by garbage (its sync is gone)
    d = StreamDecoder()
    out = d.feed(b"".join(fs))
    assert [f.seq for f in out] == [0, 1, 2, 4, 5, 7, 8, 10, 11]
    s = d.stats
    assert (s.crc_errors, s.truncated, s.seq_gaps, s.lost_frames) == (1, 1, 3, 3)
    assert s.bytes_discarded == 34 + 32 + 7
    assert accounted(d) == s.bytes_in


def test_sequence_reset_is_not_a_loss():
    d = StreamDecoder()
    out = d.feed(b"".join(frames(5, start=100) + frames(5, start=0)))
    assert len(out) == 10 and d.stats.seq_resets == 1 and d.stats.lost_frames == 0


def test_sequence_wraps_without_a_gap():
    d = StreamDecoder()
    out = d.feed(b"".join(encode_frame(2**32 - 2 + k, 0, (0, 0, 0, 0)) for k in range(4)))
    assert [f.seq for f in out] == [2**32 - 2, 2**32 - 1, 0, 1]
    assert d.stats.seq_gaps == d.stats.seq_resets == 0


def test_one_byte_at_a_time_equals_all_at_once():
    fs = [bytearray(f) for f in frames(30)]
    del fs[5][30:]  # truncated at its very end: the next sync straddles reads
    fs[11][15] ^= 0xFF
    rnd = random.Random(4)
    data = rnd.randbytes(40) + b"".join(fs) + rnd.randbytes(40)
    whole = StreamDecoder()
    out_whole = whole.feed(data)
    byte = StreamDecoder()
    out_byte = [f for b in data for f in byte.feed(bytes([b]))]
    assert out_byte == out_whole and byte.stats == whole.stats and byte.pending == whole.pending
    assert whole.stats.truncated == 1 and whole.stats.crc_errors == 1


def test_garbage_without_sync_does_not_accumulate():
    d = StreamDecoder()
    for _ in range(100):
        d.feed(bytes(1000))
    assert d.pending <= 1 and d.stats.startup_bytes == 100_000
