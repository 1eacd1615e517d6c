"""CPU cost of test modules, or of collecting the suite, one command:

    python benchmarks/bench_tests.py tests/test_structure.py tests/test_dry_run_imports.py   # each, median of 3
    python benchmarks/bench_tests.py --collect    # collecting the whole suite (every xdist worker pays it once)

CPU seconds (user + sys) of ``python -m pytest`` on each target, counting every process it starts: the CLI
subprocesses, the emulated peers, and a process pool's workers behind its fork server, which ``/usr/bin/time``
misses when they outlive the process that started them (this command is their subreaper; Linux). CPU time is the
figure a shared 2-core machine does not distort much; the wall time beside it follows the machine's load.
pytest runs as ``make test`` runs it (byte code cached), in one process; median of ``--repeats`` runs.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PR_SET_CHILD_SUBREAPER = 36  # linux/prctl.h


def become_subreaper() -> bool:
    """Orphans of our descendants come to us (and their CPU into our children's usage); False where not Linux."""
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def measure(args: list[str]) -> tuple[float, float, int]:
    """(CPU s of the run and every descendant, wall s, pytest's exit code) of ``python -m pytest ARGS``."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    cmd = [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-q", *args]
    before, t0 = children_cpu_s(), time.monotonic()
    code = subprocess.run(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
    while True:  # the orphans left behind (a fork server, its workers) end when their parent's pipes close
        try:
            os.wait()
        except ChildProcessError:
            break
    return children_cpu_s() - before, time.monotonic() - t0, code


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("targets", nargs="*", help="test modules or node ids (pytest's syntax)")
    ap.add_argument("--collect", action="store_true", help="measure collecting the whole suite instead")
    ap.add_argument("--repeats", type=int, default=3)
    opts = ap.parse_args()
    if not opts.collect and not opts.targets:
        ap.error("give test modules, or --collect")
    if not become_subreaper():
        print("not Linux: processes that outlive their parent are not counted", file=sys.stderr)
    runs = {"collect tests/": ["--collect-only", "tests"]} if opts.collect else {t: [t] for t in opts.targets}
    print(f"{'target':<60} {'CPU s':>7} {'wall s':>7}  CPU s of each run")
    for name, args in runs.items():
        results = [measure(args) for _ in range(opts.repeats)]
        failed = [code for _, _, code in results if code != 0]
        cpu = statistics.median(r[0] for r in results)
        wall = statistics.median(r[1] for r in results)
        each = " ".join(f"{r[0]:.2f}" for r in results)
        print(
            f"{name:<60} {cpu:>7.2f} {wall:>7.1f}  {each}" + (f"  (pytest exit {failed})" if failed else ""), flush=True
        )


if __name__ == "__main__":
    main()
