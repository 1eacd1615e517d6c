"""Same seed → same point: three small calibrations whose budget never binds, so the point found depends only on
the inputs and the seed (not on the machine's load) — run it before and after a change to the calibrator and
compare the printed points exactly.

    python benchmarks/bench_calibrate_same_point.py --out /tmp/same_point [--cases tiny,paper,walker]

Cases (two workers each; the search's knobs are in ``CASES``):

- ``tiny``: the test suite's tiny calibration (a twin-made map, gap known; b_scale and preload_mm free; verify
  stage on the truth's protocol);
- ``paper``: the paper's contact targets, the default unknowns; lines, landmark steps, one generation, refine,
  bracket (no verify stage: the shipped protocol's runs would dominate);
- ``walker``: the paper's walker targets.

Measured 2026-12-02 (branch calib, before = main at 70a0678, after = the calibration package), identical to the
last digit before and after (values, J, evaluations, the history's best per batch):

- tiny: b_scale 0.8408964152537145, preload_mm 0.05587500000000006 (k_scale, friction_scale 1), J
  0.018250856037212135, 42 evaluations; resumed from its log: 0 new, the same point and report;
- paper: b_scale 1.0956949193523766, preload_mm 0.4167356804302778, friction_scale 0.9482073707054921, J
  0.11434041401111668, 33 evaluations;
- walker: foot_mass 0.0031393362621277704, friction 0.4971868315711617, J 0.1280896852728165, 22 evaluations.

Writes ``<out>/<case>/`` (each calibration's log, protocol, parameter set) and ``<out>/same_point.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

FREQS = [float(f) for f in range(20, 46, 2)]
TRUTH_PROTOCOL = (
    "name: truth\nrig: contact\nbackend: sim\nsweep: {start: 20, stop: 44, step: 2}\nsettle_s: 0.6\n"
    "record_s: 1.0\nsim: {model: prb3, params: paper, noise: false}\n"
)
WINDOWS = dict(coarse_settle_s=0.6, coarse_record_s=1.0, fine_settle_s=0.6, fine_record_s=1.0)
CASES = {
    "tiny": dict(
        coarse_step_hz=4.0,
        **WINDOWS,
        popsize=6,
        max_generations=1,
        stall_generations=2,
        good_enough=0.0,
        refine_top=1,
        verify_top=1,
        bracket_rounds=2,
        prior_rounds=3,
        line_cycles=1,
        free=("b_scale", "preload_mm"),
        fixed={"k_scale": 1.0},
    ),
    "paper": dict(
        coarse_step_hz=4.0,
        **WINDOWS,
        popsize=6,
        max_generations=1,
        stall_generations=2,
        good_enough=0.0,
        refine_top=1,
        verify_top=0,
        bracket_rounds=1,
        prior_rounds=2,
        line_cycles=1,
        landmark_rounds=3,
    ),
    "walker": dict(
        popsize=5,
        max_generations=1,
        stall_generations=1,
        good_enough=0.0,
        refine_top=1,
        verify_top=0,
        bracket_rounds=1,
        prior_rounds=1,
        line_cycles=1,
    ),
}


def targets_of(case: str):
    import pandas as pd

    from beambench.sim.settings import SimSettings
    from beambench.studies.twin_calibration import CalibrationBase
    from beambench.studies.twin_calibration.contact import simulate_contact
    from beambench.studies.twin_calibration.rig import load_targets
    from beambench.studies.twin_calibration.targets import Targets

    if case == "paper":
        return load_targets(ROOT / "calibration" / "paper_contact_targets.yaml")
    if case == "walker":
        return load_targets(ROOT / "calibration" / "paper_walker_targets.yaml")
    sim = SimSettings(settle_s=0.6, record_s=1.0, integrator="implicitfast")
    truth = simulate_contact(CalibrationBase("prb3", "paper"), {"preload_mm": 0.05}, FREQS, sim)
    cols = ["frequency_hz", "regime", "contacts_per_cycle", "in_contact_fraction"]
    steps = pd.DataFrame(truth["steps"])[cols]
    return Targets("contact", "twin", steps, protocol_text=TRUTH_PROTOCOL, prior={"params": "paper"})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_calibrate_same_point"))
    ap.add_argument("--cases", default="tiny,paper,walker")
    args = ap.parse_args()
    from beambench.studies.twin_calibration import SearchSettings, calibrate

    results = {}
    for case in [c.strip() for c in args.cases.split(",") if c.strip()]:
        t0 = time.perf_counter()
        settings = SearchSettings(budget_s=1e6, **CASES[case])
        res = calibrate(targets_of(case), args.out / case, case, workers=2, settings=settings)
        results[case] = {
            "values": res.values,
            "j": res.j,
            "evaluations": res.evaluations,
            "reused": res.reused,
            "history_best": [(h["stage"], h["n"], h["best"]) for h in res.history],
            "wall_s": round(time.perf_counter() - t0, 1),
        }
        print(case, json.dumps({k: results[case][k] for k in ("values", "j", "evaluations")}), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "same_point.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
