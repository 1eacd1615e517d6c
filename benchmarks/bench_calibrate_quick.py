"""``beambench calibrate sim --quick`` on the contact rig against its 2-minute goal, two cases:

1. ``paper``: the paper's targets (``--targets paper_contact_targets``);
2. ``session``: a twin-made session it has not seen: the shipped twin (``rod5g``/``physical``) with hidden damping
   (β 6 ms against 8.7), friction (0.9 against 1.0) and gap (h' 5.15 mm against 4.97: preload 0.91 mm against
   1.10), noise on, seed 5, 8–40 Hz in 2 Hz steps, 2 s settle and 3 s record. Once run, the session's parameter
   file is replaced by the shipped ``physical`` set, so the calibration's prior is the shipped twin, not the
   hidden one (the truth is kept beside it as ``hidden_truth.yaml``).

Per case: the command's wall time and the load average before and after (``os.getloadavg``), its evaluations, the
fitted values, the verdict, whether each landmark of the targets is within 2 Hz on the winner's map, and for the
session the hidden values against the reported intervals.

    python benchmarks/bench_calibrate_quick.py --out /tmp/bench_calibrate_quick [--cases paper,session]

Writes ``<out>/bench_calibrate_quick.json``; prints one line per case. Nothing is written outside ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import yaml

from bench_calibrate import sh as beambench  # the same `beambench` subprocess runner (this folder is on sys.path)

HIDDEN = {"beam.beta": 6.0e-3, "rig.friction": 0.9, "rig.plate_gap": 0.00515}
SESSION_PROTOCOL = """name: twin_hidden
description: twin-made contact session with hidden damping, friction and gap (calibrate --quick benchmark)
rig: contact
backend: sim
sweep: {{start: 8, stop: 40, step: 2}}
settle_s: 2.0
record_s: 3.0
amplitude_mm: 2.0
limits: {{max_frequency_hz: 45, max_current_a: 10, max_amplitude_mm: 3}}
sim: {{model: rod5g, params: {params}, twist_deg: 90, noise: true, seed: 5}}
"""


def hidden_session(out: Path) -> tuple[Path, dict[str, float]]:
    """The twin-made session and the hidden values in the calibration's units."""
    from beambench.common.resources import shipped_dir
    from beambench.sim.models.params import load_params
    from beambench.sim.models.registry import make_beam_model
    from beambench.sim.scene_params import RigParams
    from beambench.sim.scenes.contact_regimes import static_sag

    out.mkdir(parents=True, exist_ok=True)
    shipped = shipped_dir("sim_backend") / "rod_physical.yaml"
    doc = yaml.safe_load(shipped.read_text())
    doc["name"] = "hidden"
    doc["beam"]["beta"] = HIDDEN["beam.beta"]
    doc["rig"]["friction"] = HIDDEN["rig.friction"]
    doc["rig"]["plate_gap"] = HIDDEN["rig.plate_gap"]
    params = out / "session_params.yaml"
    params.write_text(yaml.safe_dump(doc, sort_keys=False))
    proto = out / "twin_hidden.yaml"
    proto.write_text(SESSION_PROTOCOL.format(params=params.resolve()))
    res, _ = beambench("run", str(proto), "--out", str(out), "--name", "twin_hidden", "--rerun", "off")
    session = Path(res.stdout.strip().splitlines()[-1])
    truth = out / "hidden_truth.yaml"
    params.rename(truth)
    params.write_text(shipped.read_text())  # the session's parameter set, as the calibration reads it: the prior
    p = load_params(str(truth), model="rod")
    sag = static_sag(make_beam_model("rod5g", p), RigParams.with_overrides(p.rig), 90.0)
    prior_beta = float(yaml.safe_load(shipped.read_text())["beam"]["beta"])
    return session, {
        "b_scale": HIDDEN["beam.beta"] / prior_beta,
        "preload_mm": 1e3 * (sag - HIDDEN["rig.plate_gap"]),
        "friction_scale": HIDDEN["rig.friction"],  # the prior's friction is 1.0
    }


def calibrate(label: str, args: list[str], out: Path, truth: dict[str, float] | None) -> dict:
    load0 = os.getloadavg()[0]
    res, wall = beambench("calibrate", "sim", *args, "--quick", "--workers", "2", "--out", str(out / label))
    load1 = os.getloadavg()[0]
    report = json.loads(next((out / label).glob("*_report.json")).read_text())
    ivals = (report["identifiability"].get("intervals") or {}).get("unknowns", {})
    row = {
        "case": label,
        "wall_s": round(wall, 1),
        "load_average": [round(load0, 2), round(load1, 2)],
        "evaluations": report["evaluations"],
        "parameters": report["parameters"],
        "objective": report["objective"],
        "verdict": [
            f"{v['target']}: twin {v['twin']} {'met' if v['met'] else 'missed'}" for v in report["verdict"]["targets"]
        ],
        "intervals": ivals,
        # the session's (or the paper's) landmarks against the winner's map: the regime map recovered within 2 Hz?
        "landmarks_within_2_hz": {
            v["target"]: v["twin"] is not None and abs(v["twin"] - v["wanted"]) <= 2.0
            for v in report["verdict"]["targets"]
            if v["unit"] == "Hz"
        },
        "last_line": res.stderr.strip().splitlines()[-1],
    }
    if truth is not None:
        row["hidden"] = {
            k: {"value": round(v, 4), "inside": k in ivals and ivals[k]["lo"] <= v <= ivals[k]["hi"]}
            for k, v in truth.items()
        }
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_calibrate_quick"))
    ap.add_argument("--cases", default="paper,session")
    args = ap.parse_args()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    cases = {c.strip() for c in args.cases.split(",")}
    rows = []
    if "paper" in cases:
        rows.append(calibrate("paper", ["--targets", "paper_contact_targets"], out, None))
        print(json.dumps(rows[-1]), flush=True)
    if "session" in cases:
        session, truth = hidden_session(out / "session_run")
        rows.append(calibrate("session", [str(session)], out, truth))
        print(json.dumps(rows[-1]), flush=True)
    (out / "bench_calibrate_quick.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
