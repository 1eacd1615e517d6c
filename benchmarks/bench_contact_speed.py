"""Benchmark: the shipped contact sweep end to end, its speed and its convergence. One command:

    python benchmarks/bench_contact_speed.py                 # 3 timed runs + the 2.5e-5 s reference, compared
    python benchmarks/bench_contact_speed.py --repeats 1 --reuse-reference

1. Speed: ``beambench run contact_sweep --rerun off`` (HDF5, analysis-ready session) ``--repeats`` times; each run's
   wall time and CPU time (user + sys of the process and its threads), the best of them, the real-time factor
   (280 s of rig time over the wall time) and the load average around each run (the machine is shared: compare
   the CPU column).
2. Convergence: the same protocol with a fixed ``--reference-dt`` (2.5e-5 s) in one piece (``sim.segments: 1``),
   then ``beambench analyze`` of both sessions. Converged means the same regime label at every step from
   ``--from-hz`` (23 Hz) up and in-contact fractions within 0.03 at every step outside the lift-off band
   (``--band`` 13–22 Hz; there a micrometre of gap flips the label at any timestep, so its labels are listed, not
   judged). The tangential force and the session's segment cuts (``/general/sim_segments``) are printed too.

Writes ``bench_out/contact_speed.json``; the reference session is kept in ``bench_out/contact_speed_reference/``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
PROTOCOL = ROOT / "protocols" / "contact_sweep.yaml"
OUT = ROOT / "bench_out"
CF_TOLERANCE = 0.03


def beambench(*args: str) -> tuple[str, float, float]:
    """Run the CLI; (stdout, wall s, CPU s of the child)."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "beambench.cli", *args], check=True, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return done.stdout, wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def run_session(protocol: Path, out: Path, name: str) -> tuple[Path, float, float]:
    stdout, wall, cpu = beambench("run", str(protocol), "--rerun", "off", "--out", str(out), "--name", name)
    return Path(stdout.strip().splitlines()[-1]), wall, cpu


def steps(session: Path) -> pd.DataFrame:
    """``beambench analyze``'s per-step table of a session."""
    report = session.with_name(session.stem + "_report")
    beambench("analyze", str(session), "--out", str(report), "--no-write")
    return pd.read_csv(report / "steps.csv")


def segments_info(session: Path) -> dict:
    """The session's ``/general/sim_segments`` (where the cut was planned and taken, the workers' CPU)."""
    from beambench.sinks.session_file.reader import read_session

    return dict(read_session(session).general.get("sim_segments") or {})


def compare(run: pd.DataFrame, ref: pd.DataFrame, from_hz: float, band: tuple[float, float]) -> dict:
    """The convergence criterion, step by step (frequency order of the protocol)."""
    f = run["frequency_hz"].to_numpy()
    lab, lab_ref = run["regime"].astype(str).to_numpy(), ref["regime"].astype(str).to_numpy()
    cf, cf_ref = run["in_contact_fraction"].to_numpy(), ref["in_contact_fraction"].to_numpy()
    ft, ft_ref = run["mean_tangential_n"].to_numpy(), ref["mean_tangential_n"].to_numpy()
    in_band = (f >= band[0]) & (f <= band[1])
    label_misses = [float(x) for x, a, b in zip(f, lab, lab_ref) if x >= from_hz and a != b]
    cf_misses = [float(x) for x, a, b, ib in zip(f, cf, cf_ref, in_band) if not ib and abs(a - b) > CF_TOLERANCE]
    above = f >= from_hz
    return {
        "converged": not label_misses and not cf_misses,
        "labels_equal_all": int((lab == lab_ref).sum()),
        "labels_equal_from_hz": int((lab[above] == lab_ref[above]).sum()),
        "steps_from_hz": int(above.sum()),
        "label_misses_from_hz": label_misses,
        "contact_fraction_misses_outside_band": cf_misses,
        "max_contact_fraction_diff_outside_band": float(abs(cf - cf_ref)[~in_band].max()),
        "mean_tangential_rel_diff_from_hz": float(
            (abs(ft - ft_ref)[above] / abs(ft_ref)[above]).mean() if above.any() else float("nan")
        ),
        "lift_off_band": [
            {"hz": float(x), "regime": str(a), "reference": str(b)}
            for x, a, b, ib in zip(f, lab, lab_ref, in_band)
            if ib
        ],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--protocol", type=Path, default=PROTOCOL)
    ap.add_argument("--reference-dt", type=float, default=2.5e-5)
    ap.add_argument("--from-hz", type=float, default=23.0)
    ap.add_argument("--band", type=float, nargs=2, default=(13.0, 22.0))
    ap.add_argument("--reuse-reference", action="store_true", help="compare with the last reference session")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    from beambench.acquisition.protocol.plan import summary
    from beambench.acquisition.protocol.schema import load_protocol

    protocol, _ = load_protocol(args.protocol)
    rig_s = float(summary(protocol, "sim")["total_duration_s"])
    result: dict = {"protocol": str(args.protocol), "rig_s": rig_s, "cpus": os.cpu_count(), "runs": []}
    with tempfile.TemporaryDirectory() as tmp:
        session = Path()
        for i in range(args.repeats):
            load0 = os.getloadavg()[0]
            session, wall, cpu = run_session(args.protocol, Path(tmp), f"speed{i}")
            run = {"wall_s": wall, "cpu_s": cpu, "loadavg": [load0, os.getloadavg()[0]]}
            result["runs"].append(run)
            print(
                f"run {i + 1}/{args.repeats}: {wall:.1f} s wall ({rig_s / wall:.1f}x), {cpu:.1f} s CPU, "
                f"load {load0:.1f}-{run['loadavg'][1]:.1f}",
                flush=True,
            )
        best_wall = min(r["wall_s"] for r in result["runs"])
        best_cpu = min(r["cpu_s"] for r in result["runs"])
        result |= {"best_wall_s": best_wall, "best_cpu_s": best_cpu, "realtime_factor": rig_s / best_wall}
        print(
            f"best of {args.repeats}: {best_wall:.1f} s wall = {rig_s / best_wall:.1f}x real time; "
            f"{best_cpu:.1f} s CPU = {rig_s / best_cpu:.1f}x per CPU second"
        )
        result["segments"] = segments_info(session)
        print("segments:", json.dumps(result["segments"]))
        workers = result["segments"].get("worker_cpu_s") or []
        if workers:  # on two idle cores the wall time is the slower worker's CPU plus start-up and writing
            print(
                f"slowest physics worker: {max(workers):.1f} s CPU (= {rig_s / max(workers):.1f}x real time); "
                f"all workers {sum(workers):.1f} s, the rest of the process {best_cpu - sum(workers):.1f} s"
            )
        ref_dir = OUT / "contact_speed_reference"
        ref_session = ref_dir / "reference.h5"
        if not (args.reuse_reference and ref_session.exists()):
            ref_dir.mkdir(parents=True, exist_ok=True)
            spec = yaml.safe_load(args.protocol.read_text())
            spec["sim"] = {**spec.get("sim", {}), "timestep": args.reference_dt, "segments": 1}
            ref_yaml = ref_dir / "reference.yaml"
            ref_yaml.write_text(yaml.safe_dump(spec, sort_keys=False))
            ref_session, wall, cpu = run_session(ref_yaml, ref_dir, "reference")
            print(f"reference at {args.reference_dt:g} s: {wall:.1f} s wall, {cpu:.1f} s CPU", flush=True)
        check = compare(steps(session), steps(ref_session), args.from_hz, tuple(args.band))
    result["convergence"] = check
    print(json.dumps(check, indent=1))
    verdict = "CONVERGED" if check["converged"] else "NOT converged"
    print(
        f"{verdict} against {args.reference_dt:g} s: labels {check['labels_equal_from_hz']}/{check['steps_from_hz']}"
        f" from {args.from_hz:g} Hz ({check['labels_equal_all']} of all); max contact-fraction difference outside "
        f"the {args.band[0]:g}-{args.band[1]:g} Hz band {check['max_contact_fraction_diff_outside_band']:.3f}"
    )
    OUT.mkdir(exist_ok=True)
    (OUT / "contact_speed.json").write_text(json.dumps(result, indent=1, default=float))


if __name__ == "__main__":
    main()
