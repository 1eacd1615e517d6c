"""Benchmark: what a ``beambench`` command costs before and around its work — the command line's start-up.

    python benchmarks/bench_cli_start.py [--repeats 7]

Times, in fresh processes, ``beambench --version``, the shipped contact sweep's ``run --dry-run`` and a one-step
sim run that records a session (0.4 s of rig time, ``--rerun off``), and prints the median wall time and the
median CPU time (user + system of the process) of each. Every ``beambench run`` a user starts, and every one the
test suite starts, pays the last line's start-up.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ONE_STEP = "name: one_step\nrig: contact\nsweep: {frequencies: [10]}\nsettle_s: 0.2\nrecord_s: 0.2\nsim: {seed: 1}\n"


def _timed(args: list[str], cwd: Path) -> tuple[float, float]:
    """Wall and CPU seconds of ``python -m beambench ARGS`` (its own CPU, from the kernel's accounting)."""
    with tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-m", "beambench", *args], cwd=cwd, stdout=subprocess.DEVNULL, stderr=err
        )
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            err.seek(0)
            sys.exit(f"beambench {' '.join(args)} exited {proc.returncode}:\n{err.read().decode(errors='replace')}")
    return wall, usage.ru_utime + usage.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "one_step.yaml").write_text(ONE_STEP)
        cases = {
            "beambench --version": ["--version"],
            "run contact_sweep --dry-run": ["run", "contact_sweep", "--dry-run"],
            "run one_step.yaml (sim, --rerun off)": ["run", "one_step.yaml", "--rerun", "off", "--out", str(folder)],
        }
        print(f"{'command':40s} {'wall s':>8s} {'CPU s':>8s}  (median of {args.repeats})")
        for name, argv in cases.items():
            runs = [_timed(argv, folder) for _ in range(args.repeats)]
            wall = statistics.median(w for w, _ in runs)
            cpu = statistics.median(c for _, c in runs)
            print(f"{name:40s} {wall:8.3f} {cpu:8.3f}")


if __name__ == "__main__":
    main()
