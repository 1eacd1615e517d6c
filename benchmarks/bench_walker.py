"""Walker (paper Sec. IV-B): numerical convergence, the 1–80 Hz speed curve, and the sensitivity to the unknowns.

    python benchmarks/bench_walker.py --goal [--repeats 3] [--segments N]   # speed, wall-time and convergence goals
    python benchmarks/bench_walker.py --check                               # the convergence criterion only
    python benchmarks/bench_walker.py --sweep [--repeats 3] [--segments N]  # the shipped sweep's wall time only
    python benchmarks/bench_walker.py [--quick] [--out DIR]                 # the tables below

``--check`` tests the convergence criterion on the shipped walker (rod5g legs, the physical set's walker block):
steady speeds at 23 and 65 Hz at the scene's timestep, a half and a quarter of it, each within 10 % of the
finest; deterministic, one run each. The tables below are the effective PRB3 walker's (``WalkerParams``' defaults). ``--sweep`` runs the shipped
``protocols/walker_sweep.yaml`` with ``beambench run --rerun off`` ``--repeats`` times (``--segments`` overrides its
``sim.segments``), prints each run's wall and CPU time, its physics workers' CPU time (the session's
``/general/sim_segments``) and the load average around it, the median wall and CPU time and the real-time factor
(goal: 240 s of rig time in ≤ 24 s), then ``beambench analyze`` of the last session: the speeds
at 23 and 65 Hz against the paper (goal: within ±30 %). ``--goal`` does both and prints a verdict per goal.
The sweep uses both cores when the protocol has ``segments: 2``: run it on an otherwise idle machine.

All other speeds are steady ones: from a settled robot, ramp at 200 turn/s², settle 3 s, record 1.5 s
(:mod:`beambench.sim.scenes.walker_batch`).

- ``walker_convergence.csv``: forward speed at 23 and 65 Hz for contact time constant × timestep, with the
  wall time per simulated second (one thread) and the deviation from the finest setting (0.25 ms, 1.25e-5 s;
  two extra rows at 0.125 ms check the time constant itself);
- ``walker_sweep.csv`` + ``walker_speed.png``: speed vs drive frequency at the scene's defaults and at the
  finest numerics, with the paper's two points (−35.7 mm/s at 23 Hz, +156.3 at 65 Hz);
- ``walker_sensitivity.csv``: speed at 23 and 65 Hz when one unknown (paper silent) is changed at a time.

Single process, single thread (mujoco.rollout without a pool).
"""

from __future__ import annotations

import argparse
import csv
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SWEEP = ROOT / "protocols" / "walker_sweep.yaml"

PAPER = {23.0: -35.7, 65.0: 156.3}  # mm/s

# (label, overrides of WalkerParams): one unknown at a time around the defaults
VARIANTS: list[tuple[str, dict[str, float]]] = [
    ("defaults", {}),
    ("offset radius 5 mm", {"eccentric_radius": 0.005}),
    ("offset radius 15 mm", {"eccentric_radius": 0.015}),
    ("spin sense reversed", {"spin": 1.0}),
    ("leg chirality swapped (L+90/R-90)", {"left_chirality": 1.0, "right_chirality": -1.0}),
    ("motor flat (mass turns in x-y, 23 mm up)", {"motor_flat": 1.0}),
    ("offset plane 10 mm above clamps (old guess)", {"rotor_height": 0.010}),
    ("plate/motor mass 110/45 g", {"plate_mass": 0.110, "motor_mass": 0.045}),
    ("leg mount +5 deg", {"leg_mount_deg": 5.0}),
    ("leg mount -5 deg", {"leg_mount_deg": -5.0}),
    ("leg mount +15 deg", {"leg_mount_deg": 15.0}),
    ("leg mount -15 deg", {"leg_mount_deg": -15.0}),
    ("foot mass 10 g at sole", {"foot_mass": 0.010}),
    ("foot mass 5 g at sole (planning-like)", {"foot_mass": 0.005}),
    ("foot mass 20 g spread on bar", {"foot_mass": 0.0, "foot_bar_mass": 0.020}),
    ("friction 0.3", {"friction": 0.3}),
    ("friction 0.8", {"friction": 0.8}),
    ("cart 130 g", {"cart_mass": 0.130}),
    ("boom (frame) 30 g", {"frame_mass": 0.030}),
    ("leg clamp offset 45 mm", {"leg_offset": 0.045}),
]


def _speed(beam, f: float, settle: float, record: float, **overrides: float) -> tuple[float, float]:
    """(steady forward speed mm/s from a settled robot, wall s per simulated s)."""
    from beambench.sim.scene_params import WalkerParams
    from beambench.sim.scenes.walker_batch import RAMP_RATE, STEADY_SETTINGS, steady_speeds

    wp = replace(WalkerParams(), **overrides)
    t0 = time.perf_counter()
    v, _ = steady_speeds(beam, [f], wp, settings=STEADY_SETTINGS.replace(settle_s=settle, record_s=record))
    sim_s = f / RAMP_RATE + settle + record + wp.preroll_s
    return float(v[0]), (time.perf_counter() - t0) / sim_s


def cli_sweep(repeats: int, segments: int | None = None) -> dict:
    """Wall/CPU time of the shipped walker sweep on the CLI (``--rerun off``), and the analyzed speeds at 23 and
    65 Hz of the last run's session."""
    import pandas as pd
    import yaml

    from beambench.acquisition.protocol.plan import summary
    from beambench.acquisition.protocol.schema import load_protocol

    protocol, _ = load_protocol(str(SWEEP))
    sim_s = float(summary(protocol, "sim")["total_duration_s"])
    walls, cpus, workers = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        path = SWEEP
        if segments is not None:
            data = yaml.safe_load(SWEEP.read_text())
            data["sim"]["segments"] = segments
            path = Path(tmp) / "walker_sweep.yaml"
            path.write_text(yaml.safe_dump(data, sort_keys=False))
        for i in range(repeats):
            load = os.getloadavg()[0]
            c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            cmd = [sys.executable, "-m", "beambench.cli", "run", str(path), "--rerun", "off", "--out", tmp]
            subprocess.run([*cmd, "--name", f"bench{i}"], check=True, capture_output=True)
            walls.append(time.perf_counter() - t0)
            c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpus.append(c1.ru_utime + c1.ru_stime - c0.ru_utime - c0.ru_stime)
            workers.append(_worker_cpu(Path(tmp) / f"bench{i}.h5"))
            print(
                f"sweep run {i + 1}/{repeats}: {walls[-1]:.1f} s wall, {cpus[-1]:.1f} s CPU (physics workers "
                f"{' + '.join(f'{c:.1f}' for c in workers[-1])} s; load {load:.2f} before, "
                f"{os.getloadavg()[0]:.2f} after)",
                flush=True,
            )
        out = Path(tmp) / "analysis"
        subprocess.run(
            [
                sys.executable,
                "-m",
                "beambench.cli",
                "analyze",
                str(Path(tmp) / f"bench{repeats - 1}.h5"),
                "--out",
                str(out),
            ],
            check=True,
            capture_output=True,
        )
        steps = pd.read_csv(out / "steps.csv")
    speeds = dict(zip(steps["frequency_hz"].astype(float), steps["body_speed_mm_s"].astype(float)))
    med, cpu = statistics.median(walls), statistics.median(cpus)
    slowest = statistics.median(max(w) for w in workers)
    print(
        f"walker sweep ({sim_s:g} s of rig time, segments {segments or protocol.sim.segments}): median wall {med:.1f} s "
        f"over {repeats} run(s) (min {min(walls):.1f}, max {max(walls):.1f}), CPU {cpu:.1f} s "
        f"({sim_s / cpu:.1f}x real time per core); real-time factor {sim_s / med:.1f}x; the slowest physics worker "
        f"{slowest:.1f} s CPU ({sim_s / slowest:.1f}x: the wall time's floor on free cores)",
        flush=True,
    )
    for f, want in PAPER.items():
        got = speeds.get(f, float("nan"))
        print(f"analyze {f:.0f} Hz: {got:+.1f} mm/s (paper {want:+.1f}: {100 * (got - want) / abs(want):+.1f} %)")
    return {"wall_s": med, "sim_s": sim_s, "speeds": {f: speeds.get(f, float("nan")) for f in PAPER}}


def _worker_cpu(session: Path) -> list[float]:
    """CPU seconds of each physics worker (segment) of a sim session (its ``/general/sim_segments``)."""
    import json

    import h5py

    with h5py.File(session, "r") as f:
        raw = f["general/sim_segments/worker_cpu_s"][()]
    return [float(c) for c in json.loads(raw.decode() if isinstance(raw, bytes) else raw)]


def shipped_walker():
    """The shipped walker sweep's legs and walker parameters (rod5g on the physical set, its walker block)."""
    from beambench.sim.models.params import load_params
    from beambench.sim.models.registry import make_beam_model
    from beambench.sim.scene_params import WalkerParams

    physical = load_params("physical", model="rod")
    return make_beam_model("rod5g", physical), WalkerParams.with_overrides(physical.walker)


def check(beam=None, wp=None) -> bool:
    """The convergence criterion: steady speeds at 23 and 65 Hz (default: the shipped walker) at the scene's
    timestep and at a half and a quarter of it all within 10 % of the finest (both frequencies in one batch each;
    the contact time constant stays, at >= 2.5 steps)."""
    from beambench.sim.scenes.walker_batch import STEADY_SETTINGS, steady_speeds

    if beam is None:
        beam, wp = shipped_walker()
    dt0 = wp.timestep
    t0, c0 = time.perf_counter(), time.process_time()
    runs = {
        dt: steady_speeds(beam, list(PAPER), wp, settings=STEADY_SETTINGS.replace(timestep=dt))
        for dt in (dt0, dt0 / 2, dt0 / 4)
    }
    ref = runs[dt0 / 4][0]
    ok = True
    for dt, (v, z) in runs.items():
        dev = np.abs(v - ref) / np.abs(ref)
        ok = ok and bool(np.all(dev <= 0.10))
        cells = ", ".join(
            f"{f:.0f} Hz {a:+.1f} mm/s ({100 * e:.1f} %, body {h:.1f} mm)" for f, a, e, h in zip(PAPER, v, dev, z)
        )
        print(f"dt {dt:.3g} s: {cells}")
    print(
        f"converged (halving dt twice moves each speed <= 10 %): {ok}; {time.perf_counter() - t0:.1f} s wall, "
        f"{time.process_time() - c0:.1f} s CPU",
        flush=True,
    )
    return ok


def _write(path: Path, rows: list[dict]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="coarse grid and sweep, no sensitivity table")
    ap.add_argument("--check", action="store_true", help="only the 5 %% convergence criterion at 23 and 65 Hz")
    ap.add_argument("--sweep", action="store_true", help="only the shipped sweep's wall time and analyzed speeds")
    ap.add_argument("--goal", action="store_true", help="--check and --sweep, with a verdict per goal")
    ap.add_argument("--repeats", type=int, default=3, help="sweep runs (median wall time)")
    ap.add_argument("--segments", type=int, default=None, help="override the sweep protocol's sim.segments")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "bench_out" / "walker")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    from beambench.sim.models.params import load_params
    from beambench.sim.models.registry import make_beam_model
    from beambench.sim.scene_params import WalkerParams
    from beambench.sim.scenes.walker_batch import RECORD_S, STEADY_SETTLE_S

    beam = make_beam_model("prb3", load_params())
    d = WalkerParams()
    if args.check:
        raise SystemExit(0 if check() else 1)
    if args.sweep or args.goal:
        res = cli_sweep(args.repeats, args.segments)
        if not args.goal:
            return
        converged = check()
        fast = res["wall_s"] <= res["sim_s"] / 10
        close = all(abs(res["speeds"][f] - v) <= 0.3 * abs(v) for f, v in PAPER.items())
        print(
            f"goal wall <= {res['sim_s'] / 10:g} s: {fast}; speeds within 30 % of the paper: {close}; converged: {converged}"
        )
        raise SystemExit(0 if fast and close and converged else 1)
    settle, record = STEADY_SETTLE_S, RECORD_S  # the speed needs ~3 s from rest to be steady

    # 1. convergence at 23 and 65 Hz ------------------------------------------------------------------
    tcs = (1e-3, 2.5e-4) if args.quick else (2e-3, 1e-3, 5e-4, 2.5e-4)
    dts = (1e-4, 5e-5, 2.5e-5) if args.quick else (1e-4, 5e-5, 2.5e-5, 1.25e-5)
    conv = []
    for tc in tcs:
        for dt in dts:
            row = {"timeconst_ms": tc * 1e3, "timestep": dt}
            walls = []
            for f in PAPER:
                v, wall = _speed(beam, f, settle, record, contact_timeconst=tc, timestep=dt)
                row[f"v{f:.0f}_mm_s"] = round(v, 2)
                walls.append(wall)
            row["wall_per_sim_s"] = round(float(np.median(walls)), 3)
            conv.append(row)
            print(row, flush=True)
    ref = conv[-1]
    if not args.quick:  # beyond the grid: is the contact time constant itself converged?
        for dt in (2.5e-5, 1.25e-5):
            row = {"timeconst_ms": 0.125, "timestep": dt}
            for f in PAPER:
                row[f"v{f:.0f}_mm_s"] = round(
                    _speed(beam, f, settle, record, contact_timeconst=1.25e-4, timestep=dt)[0], 2
                )
            row["wall_per_sim_s"] = float("nan")
            conv.append(row)
            print(row, flush=True)
    for row in conv:
        for f in PAPER:
            k = f"v{f:.0f}_mm_s"
            row[f"dev{f:.0f}_pct"] = round(100 * abs(row[k] - ref[k]) / max(abs(ref[k]), 1e-9), 1)
    _write(args.out / "walker_convergence.csv", conv)

    # 2. speed vs frequency ---------------------------------------------------------------------------
    fine = {"contact_timeconst": tcs[-1], "timestep": dts[-1]}
    freqs = sorted({1.0, *np.arange(10.0, 81.0, 10.0), 23.0, 65.0} if args.quick else {float(f) for f in range(1, 81)})
    fine_freqs = sorted(
        {1.0, *np.arange(10.0, 81.0, 10.0), 23.0, 65.0} if args.quick else {1.0, *np.arange(5.0, 81.0, 5.0), 23.0, 65.0}
    )
    settings = [("defaults", {}, freqs), ("finest", fine, fine_freqs)]
    if not args.quick:
        settings.append(("previous (1 ms, dt 1e-4)", {"contact_timeconst": 1e-3, "timestep": 1e-4}, fine_freqs))
    sweep = []
    for label, over, fs in settings:
        for f in fs:
            v, _ = _speed(beam, f, settle, record, **over)
            sweep.append({"setting": label, "frequency_hz": float(f), "speed_mm_s": round(v, 2)})
        print(label, [(float(r["frequency_hz"]), r["speed_mm_s"]) for r in sweep if r["setting"] == label], flush=True)
    _write(args.out / "walker_sweep.csv", sweep)
    _plot(sweep, args.out / "walker_speed.png", d)

    # 3. sensitivity to the unknowns ------------------------------------------------------------------
    if not args.quick:
        sens = []
        for label, over in VARIANTS:
            row = {
                "variant": label,
                **{f"v{f:.0f}_mm_s": round(_speed(beam, f, settle, record, **over)[0], 2) for f in PAPER},
            }
            sens.append(row)
            print(row, flush=True)
        _write(args.out / "walker_sensitivity.csv", sens)
    print(f"wrote {args.out}")


def _plot(sweep: list[dict], path: Path, d) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for label in dict.fromkeys(r["setting"] for r in sweep):
        rows = [r for r in sweep if r["setting"] == label]
        ax.plot([r["frequency_hz"] for r in rows], [r["speed_mm_s"] for r in rows], "o-", ms=3, label=label)
    ax.plot(list(PAPER), list(PAPER.values()), "*", color="orange", mec="k", ms=16, label="paper (Sec. IV-B)")
    ax.axhline(0, color="grey", lw=0.8)
    ax.set_xlabel("drive frequency [Hz]")
    ax.set_ylabel("body speed [mm/s] (+ away from the cart)")
    ax.set_title(f"walker: defaults = contact {d.contact_timeconst * 1e3:g} ms, dt {d.timestep:g} s")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
