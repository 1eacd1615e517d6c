"""Benchmark: the contact scene's speed/accuracy chart (model × contact formulation × integrator × timestep).

    python benchmarks/bench_contact_chart.py [--workers 2] [--models prb3 rod3g rod5g rod10] [--out CSV] [--reuse]

Runs every point of :func:`beambench.studies.contact_chart.chart_points` (a reduced stepped sweep each: 6 steps,
1 + 2 s; the state carried as ``beambench run`` does) on a local process pool, writes the per-step rows to
``sim_backend/contact_chart.csv`` (what ``docs/make_figures.py`` draws the chart from) and prints each point's
summary: CPU per simulated second, its accuracy against its own 4× finer run and against rod10, the unstable
points with their reason, and the cheapest point within tolerance (labels from 23 Hz equal to its own finer run's,
in-contact fraction within 0.03). CPU is per worker process: compare ratios within one run on a shared machine.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--models", nargs="+", default=["prb3", "rod3g", "rod5g", "rod10"])
    ap.add_argument("--out", type=Path, default=ROOT / "sim_backend" / "contact_chart.csv")
    ap.add_argument("--reuse", action="store_true", help="keep the points --out already holds, run only the others")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    import pandas as pd

    from beambench.studies.contact_chart import chart_points, run_chart, summarize

    points = chart_points(tuple(args.models))
    kept = pd.DataFrame()
    if args.reuse and args.out.exists():  # keep the points already measured, run the others
        kept = pd.read_csv(args.out)
        done = {(r.model, r.formulation, r.integrator, round(float(r.timestep), 12)) for r in kept.itertuples()}
        points = [p for p in points if (p.model, p.formulation, p.integrator, round(p.timestep, 12)) not in done]
    fresh = run_chart(points, args.workers, lambda s: print(s, flush=True)) if points else pd.DataFrame()
    table = pd.concat([kept, fresh], ignore_index=True)
    table.to_csv(args.out, index=False)
    s = summarize(table)
    pd.set_option("display.width", 250)
    pd.set_option("display.max_columns", 30)
    print(s.round(4).to_string(index=False))
    for against in ("own", "rod10"):  # converged in the timestep; and, besides, in the model
        ok = s[
            s["stable"]
            & (s[f"{against}_labels_equal_from_23hz"] == 1.0)
            & (s[f"{against}_contact_fraction_err"] <= 0.03)
            & ~s["model"].str.startswith("prb")  # PRB3 (the paper's fit) on this rig does not reach the plate
        ]
        for form, grp in ok.groupby("formulation"):
            best = grp.sort_values("cpu_s_per_sim_s").iloc[0]
            print(
                f"cheapest within tolerance against {against} ({form}): {best.model} {best.integrator} "
                f"{best.timestep:g} s ({best.cpu_s_per_sim_s:.3f} CPU s per simulated s)"
            )
    print(f"written {args.out}")


if __name__ == "__main__":
    main()
