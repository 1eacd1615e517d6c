"""Speed of the MuJoCo sim backend (contact rig, default model), one command:

    python benchmarks/bench_sim.py            # 10 s-simulated timings + the 280 s lab sweep
    python benchmarks/bench_sim.py --accuracy # also the timestep-policy accuracy table (~1 min)
    python benchmarks/bench_sim.py --e2e      # also `beambench run protocols/contact_sweep.yaml --rerun off`
    python benchmarks/bench_sim.py --sweep-only  # only the 280 s lab sweep of the shipped twin (median of 3), its
                                                 # schedule announced as the runner does (physics run ahead)
    python benchmarks/bench_sim.py --dt-check 2e-4 1e-4  # the shipped sweep's regimes and forces at each timestep

Figures are wall-clock medians of repeated runs (the machine is shared: read ratios, not absolutes) and the
CPU time of this process. Results are printed and written to ``bench_out/bench_sim.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from beambench.acquisition.capabilities import MotorLimits
from beambench.acquisition.protocol.plan import motor_limits, plan
from beambench.acquisition.protocol.schema import load_protocol, parse_protocol
from beambench.backends.sim import build_sim_rig
from beambench.backends.sim_devices import interp_rows
from beambench.session.slices import sim_slice
from beambench.sim.models.params import load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.scenes.contact_rig import ContactRigSim, default_timestep


def timed(fn, repeats: int) -> tuple[float, float]:
    """(median wall s, median CPU s of all threads) of ``fn()`` over ``repeats`` runs."""
    walls, cpus = [], []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return statistics.median(walls), statistics.median(cpus)


def rig_run(freq: float, gap_mm: float, seconds: float = 10.0, poll: float = 0.5) -> None:
    """The runner's pattern on the sim rig (0.5 s polls when not realtime): wait and read every stream."""
    rig = build_sim_rig(
        sim_slice(parse_protocol(f"sweep: {{frequencies: [{freq}]}}\nsim: {{plate_gap_mm: {gap_mm}}}\n"))
    )
    rig.open()
    rig.motor.arm(MotorLimits(80.0, 10.0, 2.0))
    rig.motor.set_frequency(freq)
    for _ in range(round(float(seconds / poll))):
        rig.clock.wait(poll)
        for s in rig.streams:
            s.read()
    rig.close()


def physics_run(freq: float, gap_mm: float, seconds: float = 10.0) -> None:
    sim = ContactRigSim(make_beam_model("prb3", load_params()), 90.0, gap_mm * 1e-3)
    sim.set_frequency(freq)
    for k in range(1, round(float(seconds / 0.1)) + 1):
        sim.advance_to(0.1 * k)


def lab_sweep(prefetch: bool = True, poll: float = 0.5, announce: bool = True) -> dict[str, float]:
    """The 40-step × 7 s contact sweep through the sim rig, every stream read each ``poll`` s (no HDF5). With
    ``announce`` (and prefetch) the schedule is announced after arming, as the runner does, so the physics of the
    whole sweep runs ahead on a worker thread; without it the rig prefetches one poll ahead (and redoes the chunk
    each new frequency invalidates)."""
    protocol, _ = load_protocol(ROOT / "protocols" / "contact_sweep.yaml")
    rig = build_sim_rig(sim_slice(protocol), prefetch=prefetch)
    steps = plan(protocol)
    polls = [round(float(step.duration_s / poll)) for step in steps]
    rows = 0
    w0, c0 = time.perf_counter(), time.process_time()
    rig.open()
    rig.motor.arm(motor_limits(protocol))
    if announce:
        rig.anticipate([(step.frequency_hz, [poll] * n) for step, n in zip(steps, polls)])
    for step, n in zip(steps, polls):
        rig.motor.set_frequency(step.frequency_hz)
        for _ in range(n):
            rig.clock.wait(poll)
            for s in rig.streams:
                rows += len(s.read())
    rig.motor.idle()
    rig.close()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    sim_s = rig.clock.now_ns() * 1e-9
    return {"simulated_s": sim_s, "wall_s": wall, "cpu_s": cpu, "realtime_factor": sim_s / wall, "rows": rows}


def protocol_model() -> str:
    """The shipped contact sweep's model and parameter set, e.g. ``rod5g/physical``."""
    protocol, _ = load_protocol(ROOT / "protocols" / "contact_sweep.yaml")
    return f"{protocol.sim.model}/{protocol.sim.params}"


def accuracy_table(freqs=(5, 10, 20, 30, 40, 60, 80), dts=(5e-5, 1e-4, 2e-4, 4e-4), gap_mm: float = 1.0) -> list[dict]:
    """Foot-path RMS error (mm) vs a dt = 2.5e-5 reference, 1 mm gap (contact), 2 s settle + 1 s window."""
    beam = make_beam_model("prb3", load_params())

    def foot(f: float, dt: float) -> np.ndarray:
        sim = ContactRigSim(beam, 90.0, gap_mm * 1e-3, timestep=dt)
        sim.set_frequency(f)
        tr = sim.advance_to(3.0)
        return interp_rows(tr.t, tr.channels["markers"][:, 2], np.arange(2.0, 3.0, 5e-4))

    out = []
    for f in freqs:
        ref = foot(f, 2.5e-5)
        row = {"frequency_hz": f, "policy_dt": default_timestep(f)}
        for dt in dts:
            err = np.sqrt(np.mean(np.sum((foot(f, dt) - ref) ** 2, axis=1))) * 1e3
            row[f"err_mm_dt{dt:g}"] = round(float(err), 4)
        out.append(row)
        print("  ", row, flush=True)
    return out


def dt_check(timesteps: list[float]) -> list[dict]:
    """The shipped contact sweep (its twin, windows and order, noise off) at each fixed timestep: per step the
    regime and the peak normal / mean tangential force, compared with the first timestep's (the reference)."""
    from beambench.sim.scenes.contact_regimes import ContactTwin, stepped_regime_map
    from beambench.sim.settings import SimSettings

    protocol, _ = load_protocol(ROOT / "protocols" / "contact_sweep.yaml")
    twin = ContactTwin(protocol.sim.model, protocol.sim.params)
    base = SimSettings(
        protocol.settle_s, protocol.record_s, protocol.sim.twist_deg, protocol.amplitude_mm * 1e-3, "implicitfast"
    )
    freqs = list(protocol.sweep.values())
    maps = {}
    for dt in timesteps:
        c0 = time.process_time()
        maps[dt] = stepped_regime_map(freqs, base.replace(timestep=dt), twin)
        print(f"  dt {dt:g}: {time.process_time() - c0:.1f} s cpu", flush=True)
    ref = maps[timesteps[0]]
    out = []
    for dt in timesteps[1:]:
        m = maps[dt]
        same = int((m["regime"] == ref["regime"]).sum())
        dfn = np.abs(m["peak_normal_n"] / ref["peak_normal_n"] - 1.0) * 100
        dft = np.abs(m["mean_tangential_n"] - ref["mean_tangential_n"]) / ref["mean_tangential_n"].abs().max() * 100
        row = {"timestep": dt, "reference": timesteps[0], "same_regime": same, "steps": len(m)}
        row |= {"max_peak_normal_pct": float(dfn.max()), "max_tangential_pct_of_max": float(dft.max())}
        row["differ_hz"] = [float(f) for f, a, b in zip(m["frequency_hz"], m["regime"], ref["regime"]) if a != b]
        out.append(row)
        print(
            f"dt {dt:g} vs {timesteps[0]:g}: same regime at {same}/{len(m)} steps (differ at {row['differ_hz']} Hz); "
            f"peak normal force up to {row['max_peak_normal_pct']:.0f} % off, mean tangential up to "
            f"{row['max_tangential_pct_of_max']:.0f} % of its largest value"
        )
    return out


def end_to_end() -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        w0 = time.perf_counter()
        subprocess.run(
            [
                sys.executable,
                "-m",
                "beambench.cli",
                "run",
                str(ROOT / "protocols" / "contact_sweep.yaml"),
                "--rerun",
                "off",
                "--out",
                tmp,
            ],
            check=True,
            capture_output=True,
        )
        wall = time.perf_counter() - w0
    return {"wall_s": wall, "realtime_factor": 280.0 / wall}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--accuracy", action="store_true", help="also the timestep-policy accuracy table")
    ap.add_argument("--e2e", action="store_true", help="also time `beambench run` of the lab sweep (with HDF5)")
    ap.add_argument("--sweep-only", action="store_true", help="only the lab sweep (prefetch on) of the shipped twin")
    ap.add_argument(
        "--no-announce", action="store_true", help="--sweep-only without announcing the schedule (no lookahead)"
    )
    ap.add_argument("--dt-check", type=float, nargs="+", metavar="DT", help="regimes and forces at each timestep")
    args = ap.parse_args()
    results: dict[str, object] = {"per_10s": []}
    if args.dt_check:
        dt_check(args.dt_check)
        return
    if args.sweep_only:
        sweeps = [lab_sweep(True, announce=not args.no_announce) for _ in range(args.repeats)]
        med = sorted(sweeps, key=lambda r: r["wall_s"])[len(sweeps) // 2]
        each = ", ".join(f"{r['realtime_factor']:.0f}x" for r in sweeps)
        print(
            f"lab sweep ({protocol_model()}) 40 x 7 s = {med['simulated_s']:.0f} s simulated: {med['wall_s']:.2f} s wall "
            f"(cpu {med['cpu_s']:.2f} s), real-time factor {med['realtime_factor']:.0f}x (median of {len(sweeps)}; "
            f"each: {each}; schedule {'not ' if args.no_announce else ''}announced; load average "
            f"{os.getloadavg()[0]:.1f})"
        )
        return
    print(f"wall (median of {args.repeats}) per 10 s simulated, contact rig, PRB3 paper, implicitfast, auto dt:")
    for freq, gap in ((20.0, 5.5), (40.0, 5.5), (40.0, 1.0), (60.0, 1.0)):
        phys = timed(lambda freq=freq, gap=gap: physics_run(freq, gap), args.repeats)
        full = timed(lambda freq=freq, gap=gap: rig_run(freq, gap), args.repeats)
        row = {
            "frequency_hz": freq,
            "gap_mm": gap,
            "dt": default_timestep(freq),
            "physics_wall_s": phys[0],
            "physics_cpu_s": phys[1],
            "rig_wall_s": full[0],
            "rig_cpu_s": full[1],
        }
        results["per_10s"].append(row)
        print(
            f"  {freq:4.0f} Hz gap {gap:3.1f} mm dt {row['dt']:.0e}: physics {phys[0]:.3f} s "
            f"(cpu {phys[1]:.3f}), physics + devices {full[0]:.3f} s (cpu {full[1]:.3f})"
        )
    for prefetch in (True, False):
        sweeps = [lab_sweep(prefetch) for _ in range(args.repeats)]
        med = sorted(sweeps, key=lambda r: r["wall_s"])[len(sweeps) // 2]
        results[f"lab_sweep_prefetch_{prefetch}"] = med
        print(
            f"lab sweep 40 x 7 s = {med['simulated_s']:.0f} s simulated, prefetch {prefetch}: {med['wall_s']:.2f} s "
            f"wall (cpu {med['cpu_s']:.2f} s), real-time factor {med['realtime_factor']:.0f}x (median of {len(sweeps)})"
        )
    if args.e2e:
        results["end_to_end"] = end_to_end()
        e = results["end_to_end"]
        print(f"beambench run contact_sweep --rerun off: {e['wall_s']:.1f} s wall, RTF {e['realtime_factor']:.0f}x")
    if args.accuracy:
        print("foot-path error vs dt (1 mm gap, reference dt 2.5e-5):")
        results["accuracy"] = accuracy_table()
    out = ROOT / "bench_out"
    out.mkdir(exist_ok=True)
    (out / "bench_sim.json").write_text(json.dumps(results, indent=2))
    print(f"written {out / 'bench_sim.json'}")


if __name__ == "__main__":
    main()
