"""Speed and accuracy of `beambench fit`, one command:

    python benchmarks/bench_fit.py              # PRB3 acceptance fit ×3, rod fit, one-generation batching
    python benchmarks/bench_fit.py --repeats 1

1. The acceptance case: a synthetic release test from known PRB3 parameters (k = 0.30 N·m/rad,
   b = 0.0035 N·m·s/rad, l2 = 27 mm) plus 0.3 mm marker noise, fitted from scratch (3 seeds of the noise):
   wall time (median), recovered parameters and their errors, final RMS / mean marker error (mm).
2. A release session from `beambench run protocols/release_test.yaml` (the paper's PRB3, 0.1 mm mocap noise),
   fitted with PRB3 and with the 10-segment rod (E, β).
3. One generation (36 candidates) evaluated three ways: one batched rollout on all cores, the same on one
   thread, and a Python loop of single simulations — what batching buys.

The machine is shared: read ratios, not absolute times. Results go to bench_out/bench_fit.json.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from beambench.sim.models.registry import make_beam_model
from beambench.sim.scenes.release import G, release_batch, release_models
from beambench.studies.fit.release import (
    PAPER_MAE_MM,
    FitOptions,
    default_base,
    fit_release,
    load_release_session,
    synthetic_release,
)
from beambench.studies.fit.space import ParamSpace

TRUTH = {"k": 0.30, "b": 0.0035, "l2": 0.027}


def acceptance(repeats: int) -> dict:
    base = default_base("prb3")
    truth = replace(
        base,
        k=TRUTH["k"],
        b=TRUTH["b"],
        k_twist=TRUTH["k"],
        b_twist=TRUTH["b"],
        l2=TRUTH["l2"],
        l3=base.length - TRUTH["l2"],
    )
    runs = []
    for seed in range(repeats):
        data = synthetic_release(truth, noise_m=3e-4, seed=seed + 1)
        t0 = time.perf_counter()
        r = fit_release(data, "prb3", FitOptions(seed=seed))
        wall = time.perf_counter() - t0
        errs = {k: r.values[k] / v - 1 for k, v in TRUTH.items()}
        runs.append(
            {
                "wall_s": wall,
                "nfev": r.nfev,
                "generations": r.generations,
                "values": r.values,
                "rel_errors": errs,
                "rms_mm": r.rms_mm,
                "mae_mm": r.mae_mm,
                "sim_wall_s": r.sim_wall_s,
                "ok": abs(errs["k"]) < 0.05 and abs(errs["l2"]) < 0.05 and abs(errs["b"]) < 0.15,
            }
        )
        print(
            f"  seed {seed}: {wall:.1f} s, {r.nfev} evals / {r.generations} gens; k {errs['k']:+.2%}, "
            f"b {errs['b']:+.2%}, l2 {errs['l2']:+.2%}; RMS {r.rms_mm:.3f} mm, mean marker error "
            f"{r.mae_mm:.3f} mm (noise floor {0.3 * math.sqrt(3):.3f} mm RMS)",
            flush=True,
        )
    return {
        "runs": runs,
        "wall_s_median": statistics.median(r["wall_s"] for r in runs),
        "all_within_tolerance": all(r["ok"] for r in runs),
    }


def session_fits() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [
                sys.executable,
                "-m",
                "beambench.cli",
                "run",
                str(ROOT / "protocols" / "release_test.yaml"),
                "--rerun",
                "off",
                "--out",
                tmp,
                "--name",
                "rel",
            ],
            check=True,
            capture_output=True,
        )
        data = load_release_session(Path(tmp) / "rel.h5")
    out = {}
    for model in ("prb3", "rod10"):
        t0 = time.perf_counter()
        r = fit_release(data, model)
        values = {k: float(v) for k, v in r.values.items()}
        out[model] = {
            "wall_s": time.perf_counter() - t0,
            "values": values,
            "rms_mm": r.rms_mm,
            "mae_mm": r.mae_mm,
            "nfev": r.nfev,
            "shift_ms": r.shift_s * 1e3,
        }
        shown = ", ".join(f"{k}={v:.4g}" for k, v in values.items())
        print(
            f"  session, {model}: {out[model]['wall_s']:.1f} s, {shown}; RMS {r.rms_mm:.3f} mm, "
            f"mean marker error {r.mae_mm:.3f} mm",
            flush=True,
        )
    return out


def batching() -> dict:
    base = default_base("prb3")
    space = ParamSpace.prb3(base)
    rng = np.random.default_rng(0)
    xs = np.array([[rng.uniform(lo, hi) for lo, hi in space.bounds()] for _ in range(36)])
    beams = [make_beam_model("prb3", space.params(x)) for x in xs]

    def batched(threads: int) -> float:
        t0 = time.perf_counter()
        release_batch(release_models(beams, timestep=2e-4), 0.2 * G, 0.4, nthread=threads)
        return time.perf_counter() - t0

    def loop() -> float:
        t0 = time.perf_counter()
        for b in beams:
            release_batch(release_models([b], timestep=2e-4), 0.2 * G, 0.4, nthread=1)
        return time.perf_counter() - t0

    res = {
        "batched_all_cores_s": statistics.median(batched(0) for _ in range(3)),
        "batched_one_thread_s": statistics.median(batched(1) for _ in range(3)),
        "python_loop_s": statistics.median(loop() for _ in range(3)),
    }
    print(
        f"  one generation of 36: batched on all cores {res['batched_all_cores_s']:.3f} s, one thread "
        f"{res['batched_one_thread_s']:.3f} s, Python loop of single runs {res['python_loop_s']:.3f} s"
    )
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=ROOT / "bench_out" / "bench_fit.json")
    args = ap.parse_args()
    print("acceptance: synthetic PRB3 release + 0.3 mm noise")
    res = {"acceptance": acceptance(args.repeats)}
    print(
        f"  median wall {res['acceptance']['wall_s_median']:.1f} s (budget 60 s on 2 cores); "
        f"paper's error vs its rig: {PAPER_MAE_MM} mm"
    )
    print("release session (sim, paper PRB3)")
    res["session"] = session_fits()
    print("batching")
    res["batching"] = batching()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=2, default=float))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
