"""``beambench calibrate sim`` end to end, each case from one run (goal: the calibrated protocol's run meets each
target transition within ± 2 Hz):

1. a session the twin made with another gap and seed (``beambench run`` on a short sweep, ``sim.plate_gap_mm``
   changed) → calibrate against the session;
2. a targets file with other numbers than the paper's (default: continuous below 15, ½ at 30, ⅓ at 42 — see
   ``--other``);
3. the paper's targets (``calibration/paper_contact_targets.yaml``).

Per case: the calibration's wall time, the fitted parameters, and the calibrated protocol's transitions — from
``beambench run`` of the written protocol then ``beambench analyze`` — against the targets (goal ± 2 Hz).

    python benchmarks/bench_calibrate.py --out /tmp/bench_calibrate [--cases 1,2,3] [--budget-s 540]

Writes ``<out>/bench_calibrate.json``; prints a table. Nothing is written outside ``--out``.

Measured 2026-12-01 (as-built PRB3 contact scene, prior = the paper set; 2-core machine shared,
load average 6–14 throughout, so ~5–10 s per evaluation instead of ~1.5 s), one run per case:

- case 1, session with gap 1.0 mm, seed 7 (4–44 Hz, 2 Hz): 559 s, 55 evaluations; k_scale 1, b_scale 1,
  gap 0.996 mm; run of the calibrated protocol: ½ at 30 Hz (session 30). The session has no continuous or ⅓ band.
- case 2, targets 15 / 30 / 42: 515 s, 54 evaluations; k_scale 0.086, b_scale 1.28, gap 7.25 mm; run: continuous
  below 10 (MISS), ½ at 32, ⅓ at 44 (within ± 2 Hz).
- case 3, paper 18 / 26 / 38: 459 s, 107 evaluations; k_scale 0.138, b_scale 1.49, gap 5.48 mm; run: continuous
  below 6 (MISS: "2"/"3" force-level bouncing at 10–17 Hz), ½ at 26, ⅓ at 39.
- case 3 again with the continuous level at −2 (the edge weighted 4× more): continuous below 17 but no ½ or ⅓ up
  to 42 Hz. This model family cannot give both the continuous band and the subharmonics with force-only
  regimes; the weighting only chooses which to lose (kept at −1).

With the shipped sweep on the ``contact_paper`` set (then the prior; load 1–5):

- case 2, targets 15 / 30 / 42: 332 s, 266 evaluations, J 0.025; k_scale 0.717, b_scale 0.679, gap 8.787 mm.
  Calibrator's map: ½ at 30, ⅓ at 41, continuous ≤ 8 then "2"/irregular to 14. Stepped run of the protocol:
  1 at 14–29, ½ at 30–40, ⅓ at 41–46 (± 2 Hz), but stray "1/2" labels at 7 and 11 Hz in the bouncing band make
  the "lowest ½" read 7, and continuous only ≤ 4.
- case 3, paper: 142 s, 186 evaluations (stall after the prior line found the set: k_scale 1, b_scale 1,
  gap 7.377 mm); stepped run: ½ at 27, ⅓ at 38 (± 2 Hz); continuous 3–9 Hz with "2" at 12–17 (edge MISS).

With the opt-in unknowns (``--free k_scale,b_scale,preload_mm,frame_mass_g,mass_dx_mm --workers 1``; load ~3.5,
one run each; details in docs/contact-twin.md):

- case 2, 15 / 30 / 42: 360 s, 164 evaluations; k_scale 0.563, b_scale 1.35, preload 0.962 mm, frame 2.76 g,
  offset 8.2 mm; run: ½ at 30, ⅓ at 41 (± 2 Hz), continuous 1–9 and 11–12 (edge MISS), no stray subharmonics.
- case 3, paper: 344 s, 146 evaluations; k_scale 0.837, b_scale 1.55, preload 0.561 mm, frame 3.35 g, offset
  3.1 mm; run: ½ at 28, ⅓ at 37 (± 2 Hz), continuous 1–4 and 6–9 (edge MISS).

From the ``contact_stuck`` prior (non-sliding sole), default unknowns, ``--workers 1 --budget-s 300``:

- case 2, 15 / 30 / 42: 222 s, 130 evaluations; k_scale 0.698, b_scale 1.63, preload 0.211 mm; run: continuous
  1–16 (± 2 Hz), ½ at 30, ⅓ at 45 (MISS by 1 Hz beyond ± 2). Another run: continuous below 21, ½ at 31, no ⅓ —
  its own (from-rest) map had continuous below 15: the calibrator fitted a different map than the run makes.

With the calibrator as documented in docs/contact-twin.md ("Calibrating to other targets"): stepped maps as the run
steps them (1 Hz steps), a transition term in the objective, default unknowns b_scale, preload_mm,
friction_scale (k at the prior's), 1-D lines from the prior before the evolution, a verify stage with the
written protocol's sweep/windows/noise (two seeds), tangential-sign weight 0.1. ``--workers 1 --budget-s 300``,
load average 2–4 (other jobs), one run each; every verify map matched the stepped run's labels except at most one
marginal step at a transition:

- case 1, session gap 1.0 mm, seed 7: 148 s, 95 evaluations; b_scale 0.917, preload 0.147 mm (gap 1.006 mm),
  friction_scale 0.751 (not identified: the paper set's sole slides either way); run: ½ at 30 (session 30) ✓.
- case 2, 15 / 30 / 42: 296 s, 79 evaluations; b_scale 0.595, preload 0.415 mm, friction_scale 0.955 (gap
  9.268 mm); run: continuous below 14 ✓, ½ at 26 (MISS by 2 Hz beyond ± 2; the verify map had 27), ⅓ at 44 ✓.
  A calibrator without the 1-D lines, with search maps without noise and one verify seed, found b_scale 2.11, preload 0.487 mm,
  friction_scale 0.814 in 240 s: run 14 / 29 / 42, all ✓ — the search finds the region in some runs only.
- case 3, paper 18 / 26 / 38 (tangential_sign {26: −1, 40: 1}): 291 s, 82 evaluations; b_scale 1, preload
  0.391 mm, friction_scale 1 (gap 9.288 mm: the shipped set with 0.01 mm less interference); run: continuous
  below 16, ½ at 26, ⅓ at 38, all ✓ (signs − / −: the 40 Hz sign is not reproduced). With the tangential weight
  at 0.5 the same search chose b_scale 0.707 (signs right, ⅓ at 42: MISS).
- another target set, 16 / 24 / 34 (``--cases 2 --other 16,24,34``), at 300 and 540 s (calibrators without the
  1-D lines): continuous below 12–13 (MISS), ½ at 24 ✓, ⅓ at 35–36 ✓ or a stray ⅓ at the edge (13 Hz; MISS). The
  maps that reach 16 / 24 / 34 need friction ×1.07–1.1 with preload ~0.3 mm, and their continuous edge is
  marginal (a ¼ or ½ label at the edge under noise). 20 / 24 / 34 is beyond the twin: friction ×1.15 (6.9) gives
  continuous below 18 with ½ at 24 and ⅓ at 37.
- case 2 again at ``--budget-s 540``: 453 s, 127 evaluations, the same point (the lines' best; the evolution's
  extra ~50 maps found nothing better) and the same run (14 / 26 / 44: ½ MISS). Not reliable yet: see
  docs/contact-twin.md for what is left.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd

from beambench.commands import EXIT_MISSED

CASE1_PROTOCOL = """name: twin_gap
description: twin-made session with another gap and seed (calibration benchmark target)
rig: contact
backend: sim
sweep: {{start: 4, stop: 44, step: 2}}
settle_s: 1.5
record_s: 3.0
amplitude_mm: 2.0
limits: {{max_frequency_hz: 45, max_current_a: 10, max_amplitude_mm: 3}}
sim: {{model: prb3, params: paper, plate_gap_mm: {gap}, twist_deg: 90, noise: true, seed: {seed}}}
"""


def sh(*args: str, timeout: float = 3600) -> tuple[subprocess.CompletedProcess, float]:
    """``beambench ARGS`` in a subprocess; a failure raises (``calibrate sim``'s ``EXIT_MISSED``, written but a
    target missed, is a result: its report's verdict says which)."""
    t0 = time.perf_counter()
    res = subprocess.run(
        [sys.executable, "-m", "beambench.cli", *args], capture_output=True, text=True, timeout=timeout
    )
    wall = time.perf_counter() - t0
    if res.returncode != 0 and not (args[:2] == ("calibrate", "sim") and res.returncode == EXIT_MISSED):
        raise RuntimeError(f"beambench {' '.join(args)} failed ({res.returncode}): {res.stderr[-2000:]}")
    return res, wall


def analyze(session: Path, out: Path) -> pd.DataFrame:
    sh("analyze", str(session), "--out", str(out))
    return pd.read_csv(out / "steps.csv")


def transitions(steps: pd.DataFrame) -> dict:
    from beambench.sim.scenes.contact_regimes import transitions as tr

    return tr(steps["frequency_hz"].to_numpy(float), list(steps["regime"].fillna("").astype(str)))


def check(target: dict, got: dict, tol: float = 2.0) -> dict:
    out = {}
    for k in ("continuous_below_hz", "half_at_hz", "third_at_hz"):
        t, g = target.get(k), got.get(k)
        if t is None:
            continue
        out[k] = {"target": t, "twin": g, "ok": g is not None and abs(g - t) <= tol}
    return out


def run_case(
    label: str, cal_args: list[str], target: dict, out: Path, budget: float, extra: list[str] | None = None
) -> dict:
    cdir = out / label
    cdir.mkdir(parents=True, exist_ok=True)
    res, wall = sh("calibrate", "sim", *cal_args, "--out", str(cdir / "cal"), "--budget-s", str(budget), *(extra or []))
    proto = Path(res.stdout.strip().splitlines()[-1])
    report = json.loads(next((cdir / "cal").glob("*_report.json")).read_text())
    run, run_wall = sh("run", str(proto), "--out", str(cdir / "run"), "--name", "calibrated", "--rerun", "off")
    steps = analyze(Path(run.stdout.strip().splitlines()[-1]), cdir / "analysis")
    got = transitions(steps)
    return {
        "case": label,
        "calibrate_wall_s": round(wall, 1),
        "evaluations": report["evaluations"],
        "objective": report["objective"],
        "parameters": report["parameters"],
        "gap_mm": report["extras"].get("gap_mm"),
        "identifiability": report["identifiability"].get("spread"),
        "protocol": str(proto),
        "run_wall_s": round(run_wall, 1),
        "target": target,
        "twin_transitions": got,
        "check": check(target, got),
        "verdict": report.get("verdict"),  # the calibrator's own, on its winner's map
        "twin_map": " ".join(f"{f:g}:{r}" for f, r in zip(steps["frequency_hz"], steps["regime"].fillna(""))),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_calibrate"))
    ap.add_argument("--cases", default="1,2,3")
    ap.add_argument("--budget-s", type=float, default=540.0)
    ap.add_argument("--gap-mm", type=float, default=1.0, help="case 1: the twin session's gap (paper set)")
    ap.add_argument("--seed", type=int, default=7, help="case 1: the twin session's seed")
    ap.add_argument("--other", default="15,30,42", help="case 2: continuous_below,half_at,third_at (Hz)")
    ap.add_argument("--free", default=None, help="unknowns to fit (calibrate sim --free), e.g. adding frame_mass_g")
    ap.add_argument("--workers", type=int, default=None, help="calibrate sim --workers (default: all cores)")
    args = ap.parse_args()
    extra = (["--free", args.free] if args.free else []) + (["--workers", str(args.workers)] if args.workers else [])
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    repo = Path(__file__).resolve().parents[1]
    cases = {c.strip() for c in args.cases.split(",")}
    results = []
    if "1" in cases:
        d = out / "case1_session"
        d.mkdir(parents=True, exist_ok=True)
        p = d / "twin_gap.yaml"
        p.write_text(CASE1_PROTOCOL.format(gap=args.gap_mm, seed=args.seed))
        res, _ = sh("run", str(p), "--out", str(d), "--name", "twin_gap", "--rerun", "off")
        session = Path(res.stdout.strip().splitlines()[-1])
        target = transitions(analyze(session, d / "analysis"))
        results.append(run_case("case1_session", [str(session)], target, out, args.budget_s, extra))
    if "2" in cases:
        c, h, t = (float(x) for x in args.other.split(","))
        f = out / "other_targets.yaml"
        f.write_text(f"rig: contact\ncontinuous_below_hz: {c:g}\nhalf_at_hz: {h:g}\nthird_at_hz: {t:g}\n")
        target = {"continuous_below_hz": c, "half_at_hz": h, "third_at_hz": t}
        results.append(run_case("case2_other_targets", ["--targets", str(f)], target, out, args.budget_s, extra))
    if "3" in cases:
        target = {"continuous_below_hz": 18.0, "half_at_hz": 26.0, "third_at_hz": 38.0}
        paper = repo / "calibration" / "paper_contact_targets.yaml"
        results.append(run_case("case3_paper", ["--targets", str(paper)], target, out, args.budget_s, extra))
    (out / "bench_calibrate.json").write_text(json.dumps(results, indent=1, default=str))
    for r in results:
        checks = ", ".join(
            f"{k.split('_')[0]} {v['target']:g}→{v['twin']} {'ok' if v['ok'] else 'MISS'}"
            for k, v in r["check"].items()
        )
        params = ", ".join(f"{k} {v:.4g}" for k, v in r["parameters"].items())
        print(
            f"{r['case']}: calibrate {r['calibrate_wall_s']} s ({r['evaluations']}), {params}, gap {r['gap_mm']:.3f} mm; "
            f"{checks}"
        )
    print(out / "bench_calibrate.json")


if __name__ == "__main__":
    main()
