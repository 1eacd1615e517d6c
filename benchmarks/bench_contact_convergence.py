"""Is the shipped contact twin converged in its timestep, and in what? One command:

    python benchmarks/bench_contact_convergence.py                       # 4e-4 2e-4 1e-4 5e-5 s, gap ±1 µm
    python benchmarks/bench_contact_convergence.py --timesteps 2e-4 1e-4 --jobs 2
    python benchmarks/bench_contact_convergence.py --timesteps 2e-4 1e-4 5e-5 2.5e-5 --reuse  # add a timestep

Runs the shipped contact sweep (``protocols/contact_sweep.yaml``: its twin, frequencies, windows and order, noise
off) as the sim backend does (:func:`beambench.sim.scenes.contact_regimes.stepped_regime_map`, the state carried
from step to step) at each fixed timestep, and at each timestep also with the plate gap h' moved by ± ``--delta-m``
(1 µm: a thousandth of the rig's build tolerance, far below anything the rig or the targets resolve).

Two questions, answered from the same runs:

- **Sensitivity**: at one timestep, how many steps change regime when the gap moves by 1 µm? Where that happens,
  one trajectory's regime is not a property of the twin (the dynamics amplify any small difference, a timestep
  change included), and comparing single trajectories across timesteps measures that sensitivity, not the
  timestep error.
- **Convergence of what the targets use**: per timestep, the landmarks (``continuous_below_hz``, ``half_at_hz``,
  ``third_at_hz``), the tangential sign at the target frequencies, the contacts per cycle averaged over the band,
  each over the perturbed runs; and, step by step, whether a timestep's regime lies within the spread the
  smallest timestep's perturbed runs show.

Prints the tables and writes ``bench_out/contact_convergence.json``. CPU time is the sum over worker processes.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

PROTOCOL = ROOT / "protocols" / "contact_sweep.yaml"
TARGET_SIGN_HZ = (26.0, 40.0)  # calibration/paper_contact_targets.yaml: tangential_sign


def one_map(dt: float, delta_m: float) -> dict:
    """The shipped sweep's regime map at timestep ``dt`` with the plate gap moved by ``delta_m``; CPU seconds."""
    from beambench.acquisition.protocol.schema import load_protocol
    from beambench.sim.models.params import load_params
    from beambench.sim.models.registry import model_family
    from beambench.sim.scenes.contact_regimes import ContactTwin, stepped_regime_map
    from beambench.sim.settings import SimSettings

    protocol, _ = load_protocol(PROTOCOL)
    model, params = protocol.sim.model, protocol.sim.params
    gap = float(load_params(params, model=model_family(model)).rig.get("plate_gap", 0.0055))
    if protocol.sim.plate_gap_mm is not None:
        gap = protocol.sim.plate_gap_mm * 1e-3
    twin = ContactTwin(model, params, {"plate_gap": gap + delta_m})
    sim = SimSettings(
        protocol.settle_s, protocol.record_s, protocol.sim.twist_deg, protocol.amplitude_mm * 1e-3, "implicitfast"
    )
    c0 = time.process_time()
    table = stepped_regime_map(list(protocol.sweep.values()), sim.replace(timestep=dt), twin)
    cols = ["frequency_hz", "regime", "contacts_per_cycle", "tangential_sign", "peak_normal_n", "mean_tangential_n"]
    return {
        "dt": dt,
        "delta_m": delta_m,
        "cpu_s": time.process_time() - c0,
        "rows": table[cols].astype({"regime": str}).to_dict("list"),
    }


def summarize(run: dict) -> dict:
    """A run's robust quantities: the landmarks, the target signs, the mean contacts per cycle over the band."""
    from beambench.sim.scenes.contact_regimes import transitions

    r = run["rows"]
    f = np.asarray(r["frequency_hz"], float)
    cpc = np.asarray(r["contacts_per_cycle"], float)
    signs = {f"sign_{hz:g}": int(r["tangential_sign"][int(np.argmin(abs(f - hz)))]) for hz in TARGET_SIGN_HZ}
    return {**transitions(f, r["regime"]), **signs, "mean_contacts_per_cycle": float(np.nanmean(cpc))}


def report(runs: list[dict], timesteps: list[float], deltas: list[float]) -> dict:
    """Sensitivity and convergence tables from the runs (printed; returned for the JSON)."""
    by = {(r["dt"], r["delta_m"]): r for r in runs}
    freqs = np.asarray(runs[0]["rows"]["frequency_hz"], float)
    ref_dt = min(timesteps)
    ref_sets = [set(by[(ref_dt, d)]["rows"]["regime"][i] for d in deltas) for i in range(len(freqs))]
    out: dict = {"reference_dt": ref_dt, "deltas_m": deltas, "per_dt": []}
    print(f"\nregimes per step (gap moved by {', '.join(f'{d * 1e6:+g}' for d in deltas)} µm):")
    print("  Hz   " + "  ".join(f"{dt:>8g}".ljust(6 * len(deltas)) for dt in timesteps))
    for i, hz in enumerate(freqs):
        cells = ["/".join(f"{by[(dt, d)]['rows']['regime'][i]:>5s}" for d in deltas) for dt in timesteps]
        print(f"  {hz:4g} " + "  ".join(cells))
    print("\nper timestep (over the perturbed runs):")
    for dt in timesteps:
        maps = [by[(dt, d)]["rows"]["regime"] for d in deltas]
        unstable = [float(hz) for i, hz in enumerate(freqs) if len({m[i] for m in maps}) > 1]
        base = by[(dt, 0.0)]["rows"]["regime"] if (dt, 0.0) in by else maps[0]
        outside = [float(hz) for i, hz in enumerate(freqs) if base[i] not in ref_sets[i]]
        sums = [summarize(by[(dt, d)]) for d in deltas]
        row = {
            "dt": dt,
            "cpu_s": float(sum(by[(dt, d)]["cpu_s"] for d in deltas)) / len(deltas),
            "steps_changed_by_gap_perturbation": unstable,
            "steps_outside_reference_spread": outside,
            "landmarks": sums,
        }
        out["per_dt"].append(row)
        keys = ("continuous_below_hz", "half_at_hz", "third_at_hz", *(f"sign_{hz:g}" for hz in TARGET_SIGN_HZ))
        marks = "; ".join(f"{k.replace('_hz', '').replace('_at', '')} {[s[k] for s in sums]}" for k in keys)
        cpc = [round(s["mean_contacts_per_cycle"], 3) for s in sums]
        print(
            f"  dt {dt:g} ({row['cpu_s']:.1f} s CPU per sweep): {len(unstable)} steps flip under ±gap perturbation "
            f"{unstable}; {len(outside)} steps outside the {ref_dt:g} s spread {outside}\n      {marks}; "
            f"mean contacts/cycle {cpc}"
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--timesteps", type=float, nargs="+", default=[4e-4, 2e-4, 1e-4, 5e-5])
    ap.add_argument("--delta-m", type=float, default=1e-6, help="gap perturbation (m), runs at 0, +delta, -delta")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes")
    ap.add_argument("--reuse", action="store_true", help="take the runs the last call wrote instead of rerunning them")
    args = ap.parse_args()
    deltas = [0.0, args.delta_m, -args.delta_m]
    jobs = [(dt, d) for dt in sorted(args.timesteps, reverse=True) for d in deltas]
    dest = ROOT / "bench_out"
    kept = {}
    if args.reuse and (dest / "contact_convergence.json").exists():
        kept = {(r["dt"], r["delta_m"]): r for r in json.loads((dest / "contact_convergence.json").read_text())["runs"]}
    todo = [j for j in jobs if j not in kept]
    w0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        fresh = {(r["dt"], r["delta_m"]): r for r in pool.map(one_map, *zip(*todo))} if todo else {}
    runs = [fresh.get(j) or kept[j] for j in jobs]
    wall = time.perf_counter() - w0
    cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = report(runs, sorted(args.timesteps, reverse=True), deltas)
    out["wall_s"], out["children_cpu_s"] = wall, cpu.ru_utime + cpu.ru_stime
    out["runs"] = runs
    print(f"\n{len(todo)} sweeps run: {wall:.0f} s wall, {out['children_cpu_s']:.0f} s CPU (workers)")
    dest.mkdir(exist_ok=True)
    (dest / "contact_convergence.json").write_text(json.dumps(out, indent=1, default=float))
    print(f"written {dest / 'contact_convergence.json'}")


if __name__ == "__main__":
    main()
