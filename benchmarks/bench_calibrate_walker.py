"""``beambench calibrate sim`` on the walker, each case from one run (goal: ± 30 % at each target frequency,
≤ 10 min wall):

1. ``paper``: the paper's speeds (``calibration/paper_walker_targets.yaml``: 23 Hz −35.7, 65 Hz +156.3);
2. ``twin``: a session the twin made with another foot mass and friction (hidden: 5 g, 0.45; 30/50/70 Hz, settle
   3 s, record 1.5 s; ``beambench run`` then calibrate against the session, speeds from ``beambench.analysis``);
3. ``other``: a targets file with other speeds (``--other``, default {25: -50, 45: 100, 65: 120});
4. ``unreachable``: {20: -20, 50: 80, 70: 120} — a 2-D scan of the box finds no (foot mass, friction) for it
   (20 Hz never −20 mm/s while 50 Hz is ≈ 80); kept to show how a failed fit reports.

Per case: the calibration's wall time, the fitted parameters, and the calibrated parameter set's steady speeds at
the target frequencies (re-evaluated independently with ``walker_batch.steady_speeds`` from the written
``*_params.yaml``) against the targets.

    python benchmarks/bench_calibrate_walker.py --out /tmp/bench_cal_walker [--cases paper,twin] [--budget-s 540]

Writes ``<out>/bench_calibrate_walker.json``; prints a table. Nothing is written outside ``--out``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import yaml

from bench_calibrate import sh  # the same `beambench` subprocess runner (this folder is on sys.path)

HIDDEN = {"foot_mass": 0.005, "friction": 0.45}
TWIN_PROTOCOL = """name: twin_walker
description: twin-made walker session with another foot mass and friction (calibration benchmark target)
rig: walker
backend: sim
sweep: {{frequencies: [30, 50, 70]}}
settle_s: 3.0
record_s: 1.5
limits: {{max_frequency_hz: 80, max_current_a: 4, max_amplitude_mm: 3}}
sim: {{model: prb3, params: {params}, twist_deg: 90, noise: true, seed: 3}}
"""
UNREACHABLE = {20: -20.0, 50: 80.0, 70: 120.0}


def twin_session(out: Path) -> Path:
    """A walker session made by the twin with the hidden foot mass and friction."""
    from beambench.common.resources import shipped_dir

    prior = yaml.safe_load((shipped_dir("sim_backend") / "prb3_paper.yaml").read_text())
    prior["name"] = "hidden"
    prior["rig"] = dict(HIDDEN)
    params = out / "hidden_params.yaml"
    params.write_text(yaml.safe_dump(prior, sort_keys=False))
    proto = out / "twin_walker.yaml"
    proto.write_text(TWIN_PROTOCOL.format(params=params.resolve()))
    res, _ = sh("run", str(proto), "--out", str(out), "--name", "twin_walker", "--rerun", "off")
    return Path(res.stdout.strip().splitlines()[-1])


def verify(protocol: Path, targets: dict[float, float]) -> dict[float, float]:
    """Steady speeds of the calibrated parameter set at the target frequencies."""
    from beambench.acquisition.protocol.schema import load_protocol
    from beambench.sim.models.params import load_params
    from beambench.sim.models.registry import make_beam_model
    from beambench.sim.scene_params import WalkerParams
    from beambench.sim.scenes.walker_batch import steady_speeds

    proto, _ = load_protocol(protocol)
    p = load_params(proto.sim.params)
    v, _ = steady_speeds(make_beam_model(proto.sim.model, p), sorted(targets), WalkerParams.with_overrides(p.rig))
    return {f: round(float(x), 1) for f, x in zip(sorted(targets), v)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--cases", default="paper,twin,other")
    ap.add_argument("--budget-s", type=float, default=540.0)
    ap.add_argument("--other", default="{25: -50, 45: 100, 65: 120}", help="speed_mm_s of case 'other' (YAML)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    from beambench.common.resources import shipped_dir
    from beambench.studies.twin_calibration.rig import load_targets, session_targets

    rows = []
    for case in args.cases.split(","):
        out = args.out / case
        out.mkdir(exist_ok=True)
        if case == "paper":
            src = shipped_dir("calibration") / "paper_walker_targets.yaml"
            targets, cli = load_targets(src), ["--targets", str(src)]
        elif case == "twin":
            session = twin_session(out)
            targets, cli = session_targets(session), [str(session)]
        else:
            speeds = UNREACHABLE if case == "unreachable" else yaml.safe_load(args.other)
            src = out / f"{case}_targets.yaml"
            src.write_text(yaml.safe_dump({"rig": "walker", "speed_mm_s": speeds}))
            targets, cli = load_targets(src), ["--targets", str(src)]
        want = {float(f): float(v) for f, v in targets.scalars["speed_mm_s"].items()}
        res, wall = sh("calibrate", "sim", *cli, "--out", str(out), "--budget-s", str(args.budget_s))
        protocol = Path(res.stdout.strip().splitlines()[-1])
        report = json.loads(next(out.glob("*_report.json")).read_text())
        got = verify(protocol, want)
        err = {f: round(100 * (got[f] - v) / abs(v), 1) for f, v in want.items()}
        row = {
            "case": case,
            "wall_s": round(wall, 1),
            "parameters": {k: round(v, 5) for k, v in report["parameters"].items()},
            "targets": want,
            "twin": got,
            "error_pct": err,
            "within_30pct": all(abs(e) <= 30 for e in err.values()),
            "verdict": report.get("verdict"),  # the calibrator's own (exit 5, EXIT_MISSED, when a speed is missed)
            "protocol": str(protocol),
        }
        rows.append(row)
        print(json.dumps(row), flush=True)
    (args.out / "bench_calibrate_walker.json").write_text(json.dumps(rows, indent=1))
    print(f"{'case':<12} {'wall s':>7}  {'within 30 %':<11} errors %")
    for r in rows:
        print(f"{r['case']:<12} {r['wall_s']:>7.0f}  {r['within_30pct']!s:<11} {r['error_pct']}")


if __name__ == "__main__":
    main()
