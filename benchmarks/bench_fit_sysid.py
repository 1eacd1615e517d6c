"""`beambench fit`'s methods side by side on the same synthetic release tests, one command:

    python benchmarks/bench_fit_sysid.py                # 3 repeats, 2 threads
    python benchmarks/bench_fit_sysid.py --repeats 1 --threads 1
    python benchmarks/bench_fit_sysid.py --coverage 20    # also: do the 95 % intervals hold 95 % of the truths?
    python benchmarks/bench_fit_sysid.py --repeats 0 --coverage 20   # the coverage alone

For each case — the twin's release test of the 5-segment rod with E and β moved from the defaults (26 MPa,
0.6 ms → 20 MPa, 1.5 ms), and of PRB3 (k, b, l2 → 0.30, 0.0035, 27 mm), 0.3 mm marker noise, 0.35 s after the
release, generated at the fit's timestep (2e-4 s, implicitfast: an exact model) — every method fits the same
data: ``sysid`` (one screening batch, then mujoco.sysid least squares), ``de`` (the paper's differential
evolution) and ``de+sysid``. Reported: wall time (median of the repeats; the fits are deterministic), rollouts,
the recovered values with their 95 % intervals and relative errors, whether each truth lies inside its
interval, and the final RMS (noise floor 0.3·√3 = 0.52 mm). ``--coverage N``: sysid on N noise draws of each case
(0.2 s windows): how often each truth lies inside its interval, the estimates' mean error and spread against
the spread the intervals predict (half-width / t₀.₉₇₅ ≈ /1.96). The machine's load average (1 min) is recorded
before and after: the machine is shared, read ratios. Results go to bench_out/bench_fit_sysid.json.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

import numpy as np

from beambench.studies.fit.release import FitOptions, ReleaseTest, default_base, fit_release, synthetic_release

NOISE = 3e-4
TEST = ReleaseTest(post_s=0.35, timestep=2e-4)
METHODS = ("sysid", "de", "de+sysid")


def cases() -> dict[str, tuple[str, object, dict[str, float]]]:
    rod = default_base("rod")
    prb3 = default_base("prb3")
    rod_truth = {"youngs_modulus": 20e6, "beta": 1.5e-3}
    prb3_truth = {"k": 0.30, "b": 0.0035, "l2": 0.027}
    return {
        "rod5": (
            "rod5",
            replace(rod, material=replace(rod.material, youngs_modulus=rod_truth["youngs_modulus"]), beta=1.5e-3),
            rod_truth,
        ),
        "prb3": (
            "prb3",
            replace(prb3, k=0.30, b=0.0035, k_twist=0.30, b_twist=0.0035, l2=0.027, l3=prb3.length - 0.027),
            prb3_truth,
        ),
    }


def run(repeats: int, threads: int) -> dict:
    out: dict = {}
    for name, (model, params, truth) in cases().items():
        data = synthetic_release(params, model=model, noise_m=NOISE, seed=7, test=TEST)
        out[name] = {}
        for method in METHODS:
            walls, r = [], None
            for _ in range(repeats):
                t0 = time.perf_counter()
                r = fit_release(data, model, FitOptions(method=method, nthread=threads))
                walls.append(time.perf_counter() - t0)
            assert r is not None
            row = {
                "wall_s_median": statistics.median(walls),
                "wall_s": walls,
                "rollouts": r.nfev,
                "steps": r.generations,
                "rms_mm": r.rms_mm,
                "values": {k: r.values[k] for k in truth},
                "intervals": {k: list(r.intervals[k]) for k in truth},
                "rel_error": {k: r.values[k] / v - 1 for k, v in truth.items()},
                "truth_inside": {k: r.intervals[k][0] <= v <= r.intervals[k][1] for k, v in truth.items()},
                "message": r.message,
            }
            out[name][method] = row
            shown = ", ".join(
                f"{k} {row['rel_error'][k]:+.2%} (±{(r.intervals[k][1] - r.intervals[k][0]) / 2 / r.values[k]:.2%}"
                f"{'' if row['truth_inside'][k] else ', truth OUTSIDE'})"
                for k in truth
            )
            print(
                f"  {name:5s} {method:9s} {row['wall_s_median']:6.1f} s  {r.nfev:5d} rollouts  "
                f"RMS {r.rms_mm:.3f} mm  {shown}",
                flush=True,
            )
    return out


def coverage(n: int, threads: int) -> dict:
    test = replace(TEST, post_s=0.2)
    out = {}
    for name, (model, params, truth) in cases().items():
        err, half = [], []
        for seed in range(100, 100 + n):
            data = synthetic_release(params, model=model, noise_m=NOISE, seed=seed, test=test)
            r = fit_release(data, model, FitOptions(nthread=threads))
            err.append([r.values[k] / v - 1 for k, v in truth.items()])
            half.append([(r.intervals[k][1] - r.intervals[k][0]) / 2 / r.values[k] for k in truth])
        e, h = np.array(err), np.array(half)
        row = {
            k: {
                "inside": float((np.abs(e[:, i]) <= h[:, i]).mean()),
                "mean_error": float(e[:, i].mean()),
                "spread": float(e[:, i].std(ddof=1)),
                "predicted_spread": float(h[:, i].mean() / 1.96),
            }
            for i, k in enumerate(truth)
        }
        out[name] = row
        print(
            f"  {name}: "
            + "; ".join(
                f"{k} inside {v['inside']:.0%}, mean {v['mean_error']:+.2%}, spread {v['spread']:.2%} "
                f"(intervals say {v['predicted_spread']:.2%})"
                for k, v in row.items()
            ),
            flush=True,
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats per method (0: skip the comparison)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--coverage", type=int, default=0, metavar="N", help="also check the intervals on N noise draws")
    ap.add_argument("--out", type=Path, default=ROOT / "bench_out" / "bench_fit_sysid.json")
    args = ap.parse_args()
    load_before = os.getloadavg()[0]
    print(f"load average before: {load_before:.2f} on {os.cpu_count()} cores; {args.threads} threads")
    res = {"cases": run(args.repeats, args.threads) if args.repeats > 0 else {}, "threads": args.threads}
    res["repeats"] = args.repeats
    if args.coverage:
        print(f"coverage of the 95 % intervals over {args.coverage} noise draws (sysid)")
        res["coverage"] = coverage(args.coverage, args.threads)
    res["load_before"], res["load_after"] = load_before, os.getloadavg()[0]
    for name, rows in res["cases"].items():
        speedup = rows["de"]["wall_s_median"] / rows["sysid"]["wall_s_median"]
        print(f"  {name}: sysid {speedup:.1f}× faster than DE (median wall)")
    print(f"load average after: {res['load_after']:.2f}")
    out = args.out if args.repeats > 0 else args.out.with_name(args.out.stem + "_coverage.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=2, default=float))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
