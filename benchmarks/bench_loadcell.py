"""Benchmark: load-cell stream decoder throughput against the 1 kHz requirement.

    python benchmarks/bench_loadcell.py [--frames 20000] [--repeats 7]

Decodes a recorded-style byte stream (from the emulated MCU, no pty) fed in reads of ~10 frames, as the
driver's reader thread sees it, for a clean link and for a faulty one (2 % CRC errors, 2 % truncated frames,
3 % garbage bursts). Prints the median frames/s over the repeats and its ratio to the 1000 frames/s the plate
sends: the share of one core the decoder needs is 1/ratio.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REQUIRED_HZ = 1000.0


def decode_rate(data: bytes, chunk: int, repeats: int) -> tuple[float, int]:
    from beambench.devices.loadcell.protocol import StreamDecoder

    rates, n = [], 0
    for _ in range(repeats):
        dec = StreamDecoder()
        t0 = time.perf_counter()
        n = 0
        for i in range(0, len(data), chunk):
            n += len(dec.feed(data[i : i + chunk]))
        rates.append(n / (time.perf_counter() - t0))
    return statistics.median(rates), n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=20000)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--chunk", type=int, default=340, help="bytes per read (340 = 10 frames)")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    import math

    from beambench.devices.loadcell.emulated_mcu import EmulatedLoadCellMCU, LinkFaults

    def force(t: float) -> tuple[float, float]:
        return (1 + math.sin(40 * t), 0.3 * math.cos(40 * t))

    cases = {
        "clean": EmulatedLoadCellMCU(force, noise_counts=20.0, seed=1),
        "faulty": EmulatedLoadCellMCU(
            force, noise_counts=20.0, faults=LinkFaults(crc_error_prob=0.02, drop_prob=0.02, garbage_prob=0.03), seed=1
        ),
    }
    for name, mcu in cases.items():
        data = mcu.render(args.frames)
        rate, n = decode_rate(data, args.chunk, args.repeats)
        print(
            f"decoder, {name} link: {n} of {args.frames} frames per pass, median {rate:,.0f} frames/s over "
            f"{args.repeats} repeats = {rate / REQUIRED_HZ:.0f}x the 1 kHz requirement "
            f"({100 * REQUIRED_HZ / rate:.2f} % of one core at 1 kHz)",
            flush=True,
        )


if __name__ == "__main__":
    main()
