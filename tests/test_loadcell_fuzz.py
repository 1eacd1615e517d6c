"""Fuzzing the load-cell serial decoder: arbitrary bytes, garbage around valid frames, corrupted frames."""

from datetime import timedelta

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from beambench.devices.loadcell.protocol import (
    FRAME_LEN,
    Frame,
    LoadCellParseError,
    StreamDecoder,
    decode_frame,
    encode_frame,
)
from conftest import fuzz_examples

# deadline: a time bound per example (a decoder that loops fails it); generous, speed is in benchmarks/
FUZZ = settings(
    max_examples=fuzz_examples(200), deadline=timedelta(seconds=5), suppress_health_check=[HealthCheck.too_slow]
)
u32 = st.integers(0, 2**32 - 1)
i32 = st.integers(-(2**31), 2**31 - 1)
frame_fields = st.tuples(u32, u32, st.tuples(i32, i32, i32, i32), u32)


@st.composite
def frame_runs(draw, max_frames=12):
    """Consecutive valid frames (consecutive seq, so no gaps) with arbitrary payloads."""
    seq0 = draw(u32)
    fields = draw(st.lists(st.tuples(u32, st.tuples(i32, i32, i32, i32), u32), min_size=1, max_size=max_frames))
    return [encode_frame(seq0 + k, t, c, e) for k, (t, c, e) in enumerate(fields)]


def feed_in_chunks(dec: StreamDecoder, data: bytes, cuts: list[int]) -> list[Frame]:
    out, prev = [], 0
    for c in [*sorted(set(x % (len(data) + 1) for x in cuts)), len(data)]:
        out += dec.feed(data[prev:c])
        prev = c
    return out


def accounting_holds(d: StreamDecoder) -> bool:
    s = d.stats
    return FRAME_LEN * s.frames + s.unsupported_bytes + s.bytes_discarded + s.startup_bytes + d.pending == s.bytes_in


@FUZZ
@given(st.binary(max_size=2000), st.lists(st.integers(0, 4000), max_size=20))
def test_arbitrary_bytes_never_raise(data, cuts):
    d = StreamDecoder()
    out = feed_in_chunks(d, data, cuts)
    assert all(isinstance(f, Frame) for f in out)
    assert accounting_holds(d)
    assert d.pending < 600  # at most one candidate (255 + 5 bytes) and its look-ahead is ever held


@FUZZ
@given(st.binary(max_size=300))
def test_decode_frame_raises_only_its_own_error(data):
    try:
        f = decode_frame(data)
    except LoadCellParseError:
        return
    assert encode_frame(f.seq, f.t_us, f.counts, f.sync_edges) == data


@FUZZ
@given(frame_fields)
def test_single_frame_roundtrip(fields):
    seq, t, c, e = fields
    assert decode_frame(encode_frame(seq, t, c, e)) == Frame(1, seq, t, c, e)


@FUZZ
@given(st.binary(max_size=400), frame_runs(), st.binary(max_size=50), st.lists(st.integers(0, 2000), max_size=10))
def test_valid_frames_after_garbage_are_all_recovered(garbage, run, tail, cuts):
    d = StreamDecoder()
    out = feed_in_chunks(d, garbage + b"".join(run) + tail, cuts)
    assert out == [decode_frame(f) for f in run]
    assert d.stats.lost_frames == 0 and d.stats.crc_errors == 0 and accounting_holds(d)


@FUZZ
@given(frame_runs(max_frames=8), st.lists(st.binary(max_size=60), min_size=8, max_size=8))
def test_garbage_between_frames_loses_no_frame(run, garbages):
    d = StreamDecoder()
    out = d.feed(b"".join(g + f for g, f in zip(garbages, run)))
    assert out == [decode_frame(f) for f in run]
    assert d.stats.lost_frames == 0


@st.composite
def corrupted_stream(draw):
    """Valid frames, then a few corruptions: bit flips, deleted runs, inserted bytes. Returns what was touched."""
    run = draw(frame_runs(max_frames=10))
    data = bytearray(b"".join(run))
    n = len(data)
    ops = draw(st.lists(st.tuples(st.sampled_from("fdi"), st.integers(0, n - 1), st.integers(0, 255)), max_size=4))
    touched: set[int] = set()  # indices of frames whose bytes were changed
    limit = n  # ops apply from the end; each stays below the previous one, so original positions stay valid
    for kind, pos, v in sorted(ops, key=lambda op: op[1], reverse=True):
        if pos >= limit:
            continue
        prev, limit = limit, pos
        if kind == "f":
            data[pos] ^= 1 << (v % 8)
            touched.add(pos // FRAME_LEN)
        elif kind == "d":
            stop = min(pos + 1 + v % 5, prev)
            del data[pos:stop]
            touched.update(range(pos // FRAME_LEN, (stop - 1) // FRAME_LEN + 1))
        else:
            data[pos:pos] = bytes([v]) * (1 + v % 3)
            if pos % FRAME_LEN:  # at a frame boundary it touches no frame at all
                touched.add(pos // FRAME_LEN)
    return run, bytes(data), touched


@FUZZ
@given(corrupted_stream(), st.lists(st.integers(0, 400), max_size=8))
def test_corrupted_frames_never_raise_and_untouched_frames_survive(case, cuts):
    run, data, touched = case
    d = StreamDecoder()
    out = feed_in_chunks(d, data, cuts)
    originals = [decode_frame(f) for f in run]
    assert all(f in originals for f in out)  # nothing invented
    survivors = [f for k, f in enumerate(originals) if k not in touched]
    assert all(f in out for f in survivors)  # nothing untouched lost
    assert out == [f for f in originals if f in out]  # in order
    if out:  # every frame missing between the first and the last decoded one is counted as lost
        assert d.stats.lost_frames == (out[-1].seq - out[0].seq) % 2**32 + 1 - len(out)
    assert accounting_holds(d)


@FUZZ
@given(corrupted_stream(), st.binary(max_size=100), st.lists(st.integers(0, 400), max_size=12))
def test_result_does_not_depend_on_how_bytes_arrive(case, garbage, cuts):
    _, data, _ = case
    data = garbage + data
    whole = StreamDecoder()
    out_whole = whole.feed(data)
    chunked = StreamDecoder()
    out_chunked = feed_in_chunks(chunked, data, cuts)
    assert out_chunked == out_whole and chunked.stats == whole.stats and chunked.pending == whole.pending
