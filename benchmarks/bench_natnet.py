"""NatNet decoder benchmark: frames decoded per second, medians of repeated runs.

Run: ``python benchmarks/bench_natnet.py [--repeats 7]`` (about 10 s). Wall time on a shared machine is noisy:
compare the ratios (and against the 360 Hz a rig needs) rather than the absolute numbers.

1. the real Motive 2.1 capture's 518 frames (NatNet 3.0, 1 rigid body, 6 labeled markers, 5 other markers),
   decoded from bytes (if ../shared exists);
2. the emulator's 4.1 frames (3 markers in a marker set + labeled markers, precision timestamp);
3. a crowded 4.1 frame (200 labeled markers, 10 rigid bodies);
4. the mocap stream's own path for those 4.1 frames, 36 at a time (what one 100 ms poll reads at 360 Hz) to a
   Batch: the codec frame by frame then ``to_batch``, against ``raw_to_batch`` (frames of one layout decoded
   together with numpy, :mod:`beambench.devices.natnet.block`);
5. ``decode_capture`` end to end: pcapng → UDP → frames (if ../shared exists);
6. the same 4.1 frames through the PyPI ``natnet`` package's decoder, if installed (reference ratio).
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path

from beambench.devices.natnet import frame as nf
from beambench.devices.natnet import protocol as nn
from beambench.devices.natnet import wire as nw
from beambench.devices.natnet.emulated_motive import MotiveEmulator

CAPTURE = Path(__file__).resolve().parents[1] / ".." / "shared" / "fixtures" / "natnet" / "traffic.pcapng"


def rate(fn: Callable[[], int], repeats: int) -> float:
    """Median frames/s of ``fn`` (which returns how many frames it decoded)."""
    fn()  # warm up
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        n = fn()
        out.append(n / (time.perf_counter() - t))
    return statistics.median(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    rows: list[tuple[str, float]] = []

    if CAPTURE.is_file():
        from beambench.devices.natnet.capture import decode_capture
        from beambench.devices.natnet.pcap import read_udp

        real = [g.payload for g in read_udp(CAPTURE, [1511]) if nn.peek_message_id(g.payload) == 7] * 4
        rows.append(
            (
                "real capture frames (3.0, 6 markers)",
                rate(lambda: sum(1 for p in real if nn.decode(p, nw.V3_0)), args.repeats),
            )
        )
    else:
        print(f"(skipping the real capture: {CAPTURE} not found)")

    emu = MotiveEmulator(version="4.1", rigid_bodies={1: [0, 1, 2]})
    small = [nn.encode(emu.make_frame(k, 1.0 + k / 360, 1.001 + k / 360, set()), nw.V4_1) for k in range(2000)]
    rows.append(
        ("emulator frames (4.1, 3 markers)", rate(lambda: sum(1 for p in small if nn.decode(p, nw.V4_1)), args.repeats))
    )

    # the mocap stream's path: the packets of one 100 ms poll (36 frames at 360 Hz) to a Batch
    from beambench.devices.natnet.client import NatNetClient
    from beambench.devices.natnet.mocap import NatNetMocap

    names = [f"m{i}" for i in range(len(emu.marker_ids))]  # type: ignore[arg-type]
    mocap = NatNetMocap(names, marker_map=dict(zip(names, emu.marker_ids, strict=True)))  # type: ignore[arg-type]
    client = NatNetClient()
    chunks = [small[i : i + 36] for i in range(0, len(small), 36)]

    def one_by_one() -> int:
        for chunk in chunks:
            mocap.to_batch([(0, nn.decode(p, nw.V4_1)) for p in chunk], None)  # type: ignore[misc]
        return len(small)

    def in_blocks() -> int:
        for chunk in chunks:
            mocap.raw_to_batch([(0, p, nw.V4_1) for p in chunk], client)
        return len(small)

    rows.append(("mocap stream, codec + to_batch per frame", rate(one_by_one, args.repeats)))
    rows.append(("mocap stream, 36-frame blocks (natnet.block)", rate(in_blocks, args.repeats)))

    crowd = nf.FrameOfData(
        1,
        rigid_bodies=tuple(nf.RigidBody(i, (0.1, 0.2, 0.3), (0.0, 0.0, 0.0, 1.0), 1e-4, 1) for i in range(10)),
        labeled_markers=tuple(nf.LabeledMarker((1 << 16) | i, (0.1, 0.2, 0.3), 0.014, 2, 1e-4) for i in range(200)),
    )
    big = [nn.encode(crowd, nw.V4_1)] * 300
    rows.append(
        ("crowded frames (4.1, 200 markers)", rate(lambda: sum(1 for p in big if nn.decode(p, nw.V4_1)), args.repeats))
    )

    if CAPTURE.is_file():
        rows.append(
            ("decode_capture pcapng end to end", rate(lambda: len(decode_capture(CAPTURE).frames), args.repeats))
        )

    try:
        from natnet.data_frame import DataFrame
        from natnet.packet_buffer import PacketBuffer
        from natnet.version import Version as TheirVersion

        def theirs() -> int:
            for p in small:
                DataFrame.read_from_buffer(PacketBuffer(p[4:]), TheirVersion(4, 1))
            return len(small)

        rows.append(("PyPI natnet 0.3.0, emulator frames (4.1)", rate(theirs, args.repeats)))
    except ImportError:
        print("(PyPI 'natnet' not installed: no reference ratio)")

    width = max(len(r[0]) for r in rows)
    print(f"{'NatNet decode':<{width}}  frames/s   × 360 Hz")
    for label, fps in rows:
        print(f"{label:<{width}}  {fps:>9,.0f}  {fps / 360:>8,.0f}")
    print(f"(median of {args.repeats} runs each)")


if __name__ == "__main__":
    main()
