"""Benchmark: the model-fidelity ladder (full) and the contact-rig cost, with the issue-3 goals checked.

    python benchmarks/bench_models.py [--out bench_out/models_full] [--part all|ladder|contact|contact-timing] [--ship]

- ladder: every model × integrator × timestep on the free beam (see ``beambench.studies.ladder.run``): CSVs, the
  speed-vs-accuracy chart and the stability map in ``--out``; ``--ship`` copies the table to
  ``sim_backend/ladder_table.csv`` (what ``beambench.sim.selection`` reads).
- contact: the contact table (PRB3, 1 mm gap: foot-path error vs a 2.5e-5 s run, contacts per cycle, wall
  per 10 s; ``--ship`` → ``sim_backend/contact_table.csv``), then the contact rig at its default model:
  10 s simulated (one thread, median of 3) at the timestep the selection picks per frequency (0.1 mm), and
  the 45-frequency × 10 s sweep batched on all cores (and, for comparison, at a fixed 1e-4 s).
  ``--model rod10 --ship`` measures another model → ``sim_backend/contact_table_rod10.csv``, which
  ``sim.model: auto`` then considers too.
- contact-timing: only the timing half of ``contact``, on the shipped ``sim_backend/contact_table.csv``.

Wall times are medians of repeated runs; on a shared machine compare the thread-CPU column too.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def ladder_part(out: Path, ship: bool) -> dict:
    from dataclasses import replace

    from beambench.studies.ladder.figures import write_outputs
    from beambench.studies.ladder.run import (
        FULL,
        pareto,
        run_ladder,
        summarize,
    )

    t0 = time.perf_counter()
    last = [0.0]

    def progress(desc: str, frac: float) -> None:
        last[0] += frac
        print(f"[{time.perf_counter() - t0:7.0f} s] {100 * last[0]:5.1f}%  {desc}", flush=True)

    cfg = replace(FULL, cache_dir=str(out / "cache"))
    table = run_ladder(cfg, progress)
    paths = write_outputs(table, out, cfg)
    if ship:
        shutil.copy(paths["table"], ROOT / "sim_backend" / "ladder_table.csv")
    s = summarize(table, FULL.error_band)
    ok = s[s.status_band.isin(["ok", "inaccurate"]) & ~s.is_reference].dropna(subset=["wall_s_per_10s"])
    prb = ok[(ok.model == "prb3") & (ok.integrator == "implicitfast") & (ok.timestep == 1e-4)].iloc[0]
    g1 = ok[(ok.err_mean_mm <= prb.err_mean_mm / 10) & (ok.wall_s_per_10s <= prb.wall_s_per_10s)]
    g1_cpu = ok[(ok.err_mean_mm <= prb.err_mean_mm / 10) & (ok.cpu_s_per_10s <= prb.cpu_s_per_10s)]
    g2 = ok[(ok.err_mean_mm <= 1.0)].sort_values("wall_s_per_10s")
    g2_cpu = ok[(ok.err_mean_mm <= 1.0)].sort_values("cpu_s_per_10s")
    cols = [
        "model",
        "integrator",
        "timestep",
        "nv",
        "err_mean_mm",
        "err_max_mm",
        "wall_s_per_10s",
        "wall_min_s_per_10s",
        "cpu_s_per_10s",
    ]
    result = {
        "minutes": (time.perf_counter() - t0) / 60,
        "prb3_implicitfast_1e-4": prb[cols].to_dict(),
        "goal1_candidates_wall": g1.sort_values("err_mean_mm")[cols].head(5).to_dict("records"),
        "goal1_candidates_cpu": g1_cpu.sort_values("err_mean_mm")[cols].head(5).to_dict("records"),
        "goal2_fastest_under_1mm_wall": g2[cols].head(5).to_dict("records"),
        "goal2_fastest_under_1mm_cpu": g2_cpu[cols].head(5).to_dict("records"),
        "pareto": pareto(s)[cols].to_dict("records"),
        "files": {k: str(v) for k, v in paths.items()},
    }
    return result


def contact_part(out: Path, ship: bool, timing_only: bool = False, model: str = "prb3") -> dict:
    from beambench.studies.contact_table import bench_contact, time_contact_goals

    if timing_only:  # the goals on the shipped table, without re-measuring it
        import pandas as pd

        return time_contact_goals(pd.read_csv(ROOT / "sim_backend" / "contact_table.csv"))
    result = bench_contact(out, model=model)
    if ship:  # prb3 is the main table; another model ships beside it (sim.model: auto reads every one)
        name = "contact_table.csv" if model == "prb3" else f"contact_table_{model}.csv"
        shutil.copy(out / "contact_table.csv", ROOT / "sim_backend" / name)
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "bench_out" / "models_full")
    ap.add_argument("--part", choices=["all", "ladder", "contact", "contact-timing"], default="all")
    ap.add_argument("--model", default="prb3", help="contact part: the model to measure (e.g. rod10)")
    ap.add_argument(
        "--ship",
        action="store_true",
        help="copy the measured tables to sim_backend/ (ladder_table.csv, contact_table.csv)",
    )
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    args.out.mkdir(parents=True, exist_ok=True)
    try:
        load = os.getloadavg()
    except OSError:
        load = (float("nan"),) * 3
    report: dict = {"cpus": os.cpu_count(), "loadavg_start": load}
    if args.part in ("all", "ladder"):
        report["ladder"] = ladder_part(args.out, args.ship)
    if args.part in ("all", "contact"):
        report["contact"] = contact_part(args.out, args.ship, model=args.model)
    if args.part == "contact-timing":
        report["contact_timing"] = contact_part(args.out, False, timing_only=True)
    report["loadavg_end"] = os.getloadavg()
    text = json.dumps(report, indent=2, default=float)
    (args.out / f"bench_models_{args.part}.json").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
