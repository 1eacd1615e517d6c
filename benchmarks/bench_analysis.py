"""Benchmark of the offline analysis: ``beambench analyze`` on a 40-step session (goal: < 20 s), and sync accuracy.

    python benchmarks/bench_analysis.py                 # 40-step sim contact sweep (made once, cached in data/)
    python benchmarks/bench_analysis.py --synthetic     # 40-step synthetic session instead (no physics)
    python benchmarks/bench_analysis.py --session S.h5  # any session
    python benchmarks/bench_analysis.py --sync          # also: 5-minute sim run with 5 ms / 50 ppm / 0.4 ms clocks
    python benchmarks/bench_analysis.py --figures none  # the same with analyze's --figures (default: all)

Times the whole command in a fresh process (imports, reading, analysis, figures, HTML), ``--repeats`` times, and
reports the median wall time and the CPU time of each run (the machine may be shared: CPU time is the steadier
figure). Exit code 1 if the median wall time misses the goal.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "data" / "bench_analysis"
GOAL_S = 20.0

SWEEP = """
name: bench_contact_gap1
description: the lab's 40-step sweep (1-40 Hz, 2 s settle, 5 s record) with a 1 mm plate gap so the foot touches
rig: contact
backend: sim
sweep: {start: 1, stop: 40, step: 1}
settle_s: 2.0
record_s: 5.0
amplitude_mm: 2.0
limits: {max_frequency_hz: 40, max_current_a: 10, max_amplitude_mm: 3}
sim: {model: prb3, params: paper, plate_gap_mm: 1.0, twist_deg: 90, noise: true, seed: 0}
"""

SYNC = """
name: bench_sync_5min
rig: contact
backend: sim
sweep: {frequencies: [5, 12, 20]}
settle_s: 0.5
record_s: 99.5
amplitude_mm: 2.0
sim:
  plate_gap_mm: 5.5
  clocks:
    mocap: {offset_s: 0.005, drift_ppm: 50, jitter_s: 0.0004}
    loadcell: {offset_s: -0.012, drift_ppm: -30, jitter_s: 0.0004}
    motor: {offset_s: 0.3, drift_ppm: 20, jitter_s: 0.001}
"""


def run_protocol(text: str, name: str) -> Path:
    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / f"{name}.h5"
    if path.exists():
        return path
    proto = CACHE / f"{name}.yaml"
    proto.write_text(text)
    print(f"making {path} with beambench run (once) ...", flush=True)
    t = time.perf_counter()
    subprocess.run(
        ["beambench", "run", str(proto), "--rerun", "off", "--out", str(CACHE), "--name", name],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    print(f"  {time.perf_counter() - t:.1f} s", flush=True)
    return path


def synthetic_session() -> Path:
    from beambench.analysis.synthetic import (
        SynthSession,
        SynthStep,
        write_synthetic_session,
    )

    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / "synthetic_40.h5"
    if not path.exists():
        steps = [SynthStep(float(f), 1 if f < 26 else (2 if f < 38 else 3)) for f in range(1, 41)]
        write_synthetic_session(path, SynthSession(steps, settle_s=2.0, record_s=5.0, mocap_dropout=0.01, seed=0))
    return path


def time_analyze(session: Path, repeats: int, figures: str = "all") -> tuple[list[float], list[float]]:
    walls, cpus = [], []
    for i in range(repeats):
        with tempfile.TemporaryDirectory() as out:
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t = time.perf_counter()
            subprocess.run(
                ["beambench", "analyze", str(session), "--out", out, "-q", "--figures", figures],
                check=True,
                stdout=subprocess.DEVNULL,
            )
            walls.append(time.perf_counter() - t)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpus.append((after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime))
        print(f"  run {i + 1}: {walls[-1]:.2f} s wall, {cpus[-1]:.2f} s CPU", flush=True)
    return walls, cpus


def sync_accuracy() -> None:
    import numpy as np

    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.analysis.session_analysis import fit_session_clocks
    from beambench.sinks.hdf5 import read_session

    path = run_protocol(SYNC, "bench_sync_5min")
    s = read_session(path)
    p = parse_protocol(s.general["protocol"])
    fits = fit_session_clocks(s)
    probe = np.linspace(0.5, float(s.streams["mocap"].device_time[-1]) - 0.5, 5000)

    def host(stream: str, clock) -> np.ndarray:
        return fits[stream].to_host_ns(clock.offset_s + (1 + clock.drift_ppm * 1e-6) * probe)

    m, lc, mo = (host(name, p.sim.clocks[name]) for name in ("mocap", "loadcell", "motor"))
    print(f"sync over {probe[-1]:.0f} s (mocap 5 ms / 50 ppm / 0.4 ms jitter; load cells -12 ms / -30 ppm / 0.4 ms):")
    print(f"  max |mocap - loadcell| alignment error: {np.max(np.abs(m - lc)) / 1e6 * 1e3:.3f} µs (goal <= 500 µs)")
    print(f"  max |mocap - motor| alignment error:    {np.max(np.abs(m - mo)) / 1e6 * 1e3:.3f} µs")
    for n, f in fits.items():
        print(
            f"  {n:9s} drift {f.drift_ppm:+8.3f} ppm  offset {f.offset_s * 1e3:+8.3f} ms  median delay {f.residual_median_us:7.1f} µs"
        )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--session", type=Path)
    ap.add_argument("--synthetic", action="store_true")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--sync", action="store_true", help="also run the 5-minute clock-sync accuracy check")
    ap.add_argument("--figures", default="all", help="analyze's --figures: all, none or names (default: all)")
    args = ap.parse_args()
    session = args.session or (synthetic_session() if args.synthetic else run_protocol(SWEEP, "bench_contact_gap1"))
    import h5py

    with h5py.File(session, "r", libver="latest", swmr=True) as f:
        n_steps = f["steps"].shape[0]
        rows = {k: f["acquisition"][k]["host_time_ns"].shape[0] for k in f["acquisition"]}
    print(f"beambench analyze {session.name} --figures {args.figures}: {n_steps} steps, rows {rows}")
    walls, cpus = time_analyze(session, args.repeats, args.figures)
    med = statistics.median(walls)
    print(
        f"median {med:.2f} s wall (min {min(walls):.2f}), median {statistics.median(cpus):.2f} s CPU; goal < {GOAL_S:.0f} s:"
        f" {'PASS' if med < GOAL_S else 'MISS'}"
    )
    if args.sync:
        sync_accuracy()
    return 0 if med < GOAL_S else 1


if __name__ == "__main__":
    sys.exit(main())
