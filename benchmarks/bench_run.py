"""Benchmark: the lab's full contact sweep on the sim backend, end to end (physics + HDF5), no viewer.

    python benchmarks/bench_run.py [--repeats 3] [--protocol protocols/contact_sweep.yaml]

Prints the median wall time of repeated `beambench run ... --rerun off` runs and the real-time factor
(simulated seconds per wall second).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--protocol", default=str(ROOT / "protocols" / "contact_sweep.yaml"))
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    from beambench.acquisition.protocol.plan import summary
    from beambench.acquisition.protocol.schema import load_protocol

    protocol, _ = load_protocol(args.protocol)
    sim_s = summary(protocol, "sim")["total_duration_s"]
    walls = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeats):
            t0 = time.perf_counter()
            subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "beambench.cli",
                    "run",
                    args.protocol,
                    "--rerun",
                    "off",
                    "--out",
                    tmp,
                    "--name",
                    f"bench{i}",
                ],
                check=True,
                capture_output=True,
            )
            walls.append(time.perf_counter() - t0)
            print(f"run {i + 1}/{args.repeats}: {walls[-1]:.2f} s wall", flush=True)
    med = statistics.median(walls)
    print(
        f"{Path(args.protocol).name}: {sim_s:g} s simulated; median wall {med:.2f} s over {args.repeats} runs; "
        f"real-time factor {sim_s / med:.1f}x (min {min(walls):.2f} s, max {max(walls):.2f} s)"
    )


if __name__ == "__main__":
    main()
