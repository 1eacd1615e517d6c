"""The stepping costs a sim dry run estimates from (``sim_backend/step_costs.csv``), measured here. One command:

    nice -n 10 python benchmarks/bench_step_costs.py --ship        # every shipped protocol no timing table covers
    python benchmarks/bench_step_costs.py my_protocol.yaml --ship   # one of your own

Per protocol: its scene built as its run builds it (:func:`beambench.session.estimate.measure_step_costs`), timed
for 0.2 simulated seconds at up to six of its drive frequencies, in CPU seconds per simulated second (CPU time,
so another program's load does not inflate it). ``--ship`` writes the rows into the table, replacing those of the
same scene, model, parameter set, integrator and timestep; without it they are printed only.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))


def uncovered_protocols() -> list[Path]:
    """The shipped protocols whose sim run no measured timing table plans (their dry run reads the cost table)."""
    from beambench.acquisition.protocol.schema import ConfigError, load_protocol
    from beambench.common.resources import shipped_dir
    from beambench.session.slices import sim_slice

    out = []
    for p in sorted(shipped_dir("protocols").glob("*.yaml")):
        try:
            protocol = load_protocol(p)[0]
        except ConfigError:  # a sweep file (beambench sweep): its runs are its base protocol's
            continue
        if sim_slice(protocol).plan is None:
            out.append(p)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("protocols", nargs="*", type=Path, help="protocol files (default: the shipped ones no table plans)")
    ap.add_argument("--ship", action="store_true", help="write the rows into sim_backend/step_costs.csv")
    args = ap.parse_args()
    from beambench.acquisition.protocol.schema import load_protocol
    from beambench.session.estimate import COST_FIELDS, COSTS_FILE, measure_step_costs, read_costs

    key = ("scene", "model", "params", "integrator", "timestep")
    new: list[dict[str, str]] = []
    for path in args.protocols or uncovered_protocols():
        rows = measure_step_costs(load_protocol(path)[0])
        for r in rows:
            print(f"{path.name}: " + ", ".join(f"{k} {r[k]}" for k in COST_FIELDS if r[k]), flush=True)
        new += [
            r
            for r in rows
            if all(any(r[k] != o[k] for k in key) or r["frequency_hz"] != o["frequency_hz"] for o in new)
        ]
    if not args.ship:
        return
    measured = {tuple(r[k] for k in key) for r in new}
    kept = [r for r in read_costs() if tuple(r[k] for k in key) not in measured]
    rows = sorted(kept + new, key=lambda r: (*(r[k] for k in key), float(r["frequency_hz"])))
    with open(COSTS_FILE, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(COST_FIELDS))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {COSTS_FILE} ({len(rows)} rows)")


if __name__ == "__main__":
    main()
