"""Scale-out of `beambench sweep`: a 500-point free-beam sweep on 1 vs 2 local worker processes, one command:

    python benchmarks/bench_sweep.py             # 3 pairs of runs, prints and writes bench_out/bench_sweep.json
    python benchmarks/bench_sweep.py --repeats 1 --dask   # also through a Dask LocalCluster (2 workers)

The sweep: 20 twist angles (0…190°) × 25 frequencies (2…50 Hz), PRB3, 0.3 s settle + 0.2 s record at
dt = 1e-4 (5000 steps per point). Reported: median wall time per configuration, the speed-up 1 → 2 workers,
the overhead = 1 − (seconds inside tasks) / (wall × workers), which includes starting the worker processes,
and the workers' CPU seconds inside tasks (unchanged from 1 to 2 workers when nothing is lost to the seam).
The machine is shared: 1- and 2-worker runs alternate in pairs, each pair with a "capacity" probe (the same
pure-Python loop in 1 and in 2 processes at once: how much parallel speed the machine offers right then); the
speed-up is the median of the per-pair ratios — read it against the capacity.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from beambench.studies.executor import make_executor, run_tasks
from beambench.studies.sweep.run import SweepSpec, run_sweep

SPEC = SweepSpec.model_validate(
    {
        "name": "bench500",
        "scene": "free_beam",
        "base": {"model": "prb3", "params": "paper", "timestep": 1e-4},
        "grid": {"twist_deg": {"start": 0, "stop": 190, "step": 10}},
        "frequencies": {"start": 2, "stop": 50, "step": 2},
        "settle_s": 0.3,
        "record_s": 0.2,
    }
)


def _noop(x: int) -> int:
    return x


def _spin(n: int) -> float:
    t0 = time.perf_counter()
    s = 0
    for i in range(n):
        s += i * i
    return time.perf_counter() - t0


def capacity(n: int = 20_000_000) -> float:
    """Parallel speed the machine offers now: 2 × (time of one loop alone) / (time of two at once)."""
    with make_executor(2) as pool:
        run_tasks(pool.executor, _noop, range(2))  # workers up
        alone = run_tasks(pool.executor, _spin, [n])[0]
        both = max(run_tasks(pool.executor, _spin, [n, n]))
    return 2 * alone / both


def pool_startup(workers: int) -> float:
    """Seconds to start ``workers`` spawned processes and get one trivial result from each."""
    t0 = time.perf_counter()
    with make_executor(workers) as pool:
        run_tasks(pool.executor, _noop, range(workers))
    return time.perf_counter() - t0


def one_run(workers: int | None = None, scheduler: str | None = None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        r = run_sweep(SPEC, Path(tmp) / "t.parquet", workers=workers, scheduler=scheduler)
        wall = time.perf_counter() - t0
    assert r.computed == 500 and bool(r.table["ok"].all())
    slots = workers or 2
    return {
        "wall_s": wall,
        "task_compute_s": r.task_compute_s,
        "task_cpu_s": r.task_cpu_s,
        "tasks": r.tasks,
        "overhead": 1 - r.task_compute_s / (wall * slots),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--dask", action="store_true", help="also run through a Dask LocalCluster (2 workers)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench_out" / "bench_sweep.json")
    args = ap.parse_args()
    assert len(SPEC.scene_points()) * len(SPEC.frequency_values()) == 500
    res: dict = {"points": 500, "steps_per_point": 5000}
    # 1- and 2-worker runs alternate (pairs), each pair with a capacity probe: on a shared machine the
    # conditions drift, so the speed-up is the median of the per-pair ratios
    pairs = []
    for i in range(args.repeats):
        cap = capacity()
        one, two = one_run(1), one_run(2)
        pairs.append({"capacity": cap, "workers_1": one, "workers_2": two, "speedup": one["wall_s"] / two["wall_s"]})
        print(
            f"pair {i + 1}: capacity {cap:.2f}x; 1 worker {one['wall_s']:.2f} s (CPU in tasks "
            f"{one['task_cpu_s']:.1f} s), 2 workers {two['wall_s']:.2f} s (CPU in tasks {two['task_cpu_s']:.1f} s, "
            f"{two['tasks']} tasks, overhead {two['overhead']:.1%}) -> speed-up {pairs[-1]['speedup']:.2f}x",
            flush=True,
        )
    res["pairs"] = pairs
    for w in (1, 2):
        runs = [p[f"workers_{w}"] for p in pairs]
        res[f"workers_{w}"] = {
            k + "_median": statistics.median(r[k] for r in runs)
            for k in ("wall_s", "task_compute_s", "task_cpu_s", "overhead")
        }
        res[f"pool_startup_s_{w}"] = statistics.median(pool_startup(w) for _ in range(args.repeats))
    res["speedup_2_vs_1"] = statistics.median(p["speedup"] for p in pairs)
    res["capacity_median"] = statistics.median(p["capacity"] for p in pairs)
    best = max(pairs, key=lambda p: p["capacity"])
    print(
        f"speed-up 1 -> 2 workers: {res['speedup_2_vs_1']:.2f}x median of {len(pairs)} pairs (machine capacity "
        f"median {res['capacity_median']:.2f}x); in the least loaded pair (capacity {best['capacity']:.2f}x): "
        f"{best['speedup']:.2f}x. Pool start-up: {res['pool_startup_s_1']:.2f} s (1), "
        f"{res['pool_startup_s_2']:.2f} s (2)."
    )
    if args.dask:
        from distributed import LocalCluster

        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
            runs = [one_run(scheduler=c.scheduler_address) for _ in range(args.repeats)]
        res["dask_2"] = {
            "wall_s_median": statistics.median(r["wall_s"] for r in runs),
            "runs": runs,
            "overhead_median": statistics.median(r["overhead"] for r in runs),
        }
        print(
            f"dask LocalCluster, 2 workers: {res['dask_2']['wall_s_median']:.2f} s wall, "
            f"overhead {res['dask_2']['overhead_median']:.1%}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
