"""Does any point of the contact twin's physical box meet the paper's ½ and ⅓? One command:

    python benchmarks/bench_contact_bounds.py --jobs 2              # ends, Sobol, confirmation: 24 CPU-min
    python benchmarks/bench_contact_bounds.py --sobol 0 --only rig.contact_timeconst,rig.contact_dampratio
    python benchmarks/bench_contact_bounds.py --jobs 2 --reuse      # only what the last run's JSON lacks

Every bounded number of the shipped twin's beam and contact rig (``sim_backend/rod_physical.yaml``'s ``bounds:``
with a ``beam.`` or ``rig.`` key: E, β, ν, the beam's mass, h', the foot, the frame's corner, its mass, the clamp
roll, friction, the contact's time constant and damping ratio) is set to its min and to its max with the rest at
the shipped point; then a scrambled Sobol sample (``--sobol`` points) spans the whole box of the unknowns that
move the map (:data:`SOBOL_KEYS`). The contact's damping ratio is varied at a fixed stiffness (the time constant
scaled by 1/ζ: MuJoCo's contact stiffness goes with 1/(tc·ζ)²).

Each point is the shipped sweep (``protocols/contact_sweep.yaml``'s frequencies, stepped with the state carried
over, as ``beambench run`` runs it: :func:`~beambench.sim.scenes.contact_regimes.stepped_regime_map`), noise off,
at a timestep ≤ min(5e-5 s, tc·ζ/20), with short windows (``--settle``/``--record``, 0.8 + 1.2 s as the
calibration's coarse stage). Points near the targets (``--confirm`` of them, most targets met first) run again with
the protocol's 2 + 5 s windows. Per point: continuous below, lowest ½, lowest ⅓, tangential sign at 26 and 40 Hz,
contacts per cycle over 26–40 Hz, the static sag and preload; then the verdict.

Writes ``bench_out/contact_bounds.json`` and ``bench_out/contact_bounds.md``; prints progress and the tables.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

PROTOCOL = ROOT / "protocols" / "contact_sweep.yaml"
TARGETS = {"continuous_below_hz": (18.0, 2.0), "half_at_hz": (26.0, 2.0), "third_at_hz": (38.0, 2.0)}
SIGNS = {26.0: -1, 40.0: 1}  # calibration/paper_contact_targets.yaml
MAX_PRELOAD_M = 2e-3  # the Sobol sample's preload range (the shipped sag's 6.07 mm less h' 4.5 mm is 1.6 mm)
# the unknowns the space-filling sample spans (the others move the map by less than a step: the ends show it)
SOBOL_KEYS = (
    "beam.material.youngs_modulus",
    "beam.beta",
    "rig.plate_gap",
    "rig.friction",
    "rig.frame_mass",
    "rig.mass_dx",
    "rig.mass_dy",
    "rig.clamp_roll_deg",
    "rig.contact_timeconst",
    "rig.contact_dampratio",
)
CODE = {"continuous": "C", "1/2": "h", "1/3": "t", "1/4": "q", "irregular": ".", "none": "-"}


def contact_keys(bounds: dict) -> list[str]:
    """The bounded numbers of the beam and the contact rig (not the walker's)."""
    return [k for k in bounds if k.startswith(("beam.", "rig."))]


def run_point(label: str, values: dict[str, float], settle: float, record: float) -> dict:
    """One point's stepped map (in a worker): landmarks, signs, contacts per cycle at 26–40 Hz, sag and preload."""
    from beambench.acquisition.protocol.schema import load_protocol
    from beambench.sim.scenes.contact_regimes import static_sag, stepped_regime_map, transitions
    from beambench.sim.scenes.contact_screen import converged_dt, point_twin
    from beambench.sim.settings import SimSettings

    protocol, _ = load_protocol(PROTOCOL)
    twin = point_twin(values)
    beam, rig = twin.build()
    dt = converged_dt(rig)
    sim = SimSettings(settle, record, protocol.sim.twist_deg, protocol.amplitude_mm * 1e-3, "implicitfast", dt)
    c0 = time.process_time()
    sag = static_sag(beam, rig, sim.twist_deg)
    table = stepped_regime_map(list(protocol.sweep.values()), sim, twin)
    f = table["frequency_hz"].to_numpy(float)
    regimes = [str(r) for r in table["regime"]]
    cpc = table["contacts_per_cycle"].to_numpy(float)
    band = (f >= 26) & (f <= 40)
    return {
        "label": label,
        "values": values,
        "settle_s": settle,
        "record_s": record,
        "dt": dt,
        **transitions(f, regimes),
        **{f"sign_{hz:g}": int(table["tangential_sign"].iloc[int(np.argmin(abs(f - hz)))]) for hz in SIGNS},
        "contacts_per_cycle_26_40": float(np.nanmean(cpc[band])),
        "sag_mm": sag * 1e3,
        "preload_mm": (sag - rig.plate_gap) * 1e3,
        "map": "".join(CODE.get(r, r[0]) for r in regimes),
        "cpu_s": time.process_time() - c0,
    }


def met(r: dict) -> dict[str, bool]:
    """Which targets a point meets."""
    out = {k: r[k] is not None and abs(r[k] - hz) <= tol for k, (hz, tol) in TARGETS.items()}
    out |= {f"sign_{hz:g}": r[f"sign_{hz:g}"] == s for hz, s in SIGNS.items()}
    return out


def near(r: dict) -> bool:
    """Worth the protocol's windows: a ½ or a ⅓ within twice the tolerance of its target."""
    return any(
        r[k] is not None and abs(r[k] - TARGETS[k][0]) <= 2 * TARGETS[k][1] for k in ("half_at_hz", "third_at_hz")
    )


def rank(r: dict) -> tuple[int, int]:
    """Confirmation order: ½ and ⅓ met first, then the most targets met."""
    m = met(r)
    return -(m["half_at_hz"] + m["third_at_hz"]), -sum(m.values())


def points(n_sobol: int, only: set[str], jobs: int) -> list[tuple[str, dict[str, float]]]:
    """The shipped point, every contact unknown at its min and its max, then the Sobol sample."""
    from beambench.sim.models.params import load_params

    bounds = load_params("physical", "rod").bounds
    keys = [k for k in contact_keys(bounds) if not only or k in only]
    out: list[tuple[str, dict[str, float]]] = [("shipped", {})]
    for k in keys:
        out += [(f"{k} min", {k: bounds[k].min}), (f"{k} max", {k: bounds[k].max})]
    return out + (sobol_points(n_sobol, bounds, jobs) if n_sobol else [])


def sag_of(values: dict[str, float]) -> float:
    """The static sag (m) of the shipped twin with ``values`` applied (in a worker)."""
    from beambench.sim.scenes.contact_regimes import static_sag
    from beambench.sim.scenes.contact_screen import point_twin

    beam, rig = point_twin(values).build()
    return static_sag(beam, rig)


def sobol_points(n: int, bounds: dict, jobs: int) -> list[tuple[str, dict[str, float]]]:
    """``n`` points of a scrambled Sobol sequence over :data:`SOBOL_KEYS` where the foot rests on the plate at
    rest, as the paper's continuous band needs: h' drawn as a preload (sag − h', 0 to :data:`MAX_PRELOAD_M`) and
    kept only where h' = sag − preload lies inside its bounds. Candidates are drawn until ``n`` are kept."""
    from scipy.stats import qmc

    dims = [k for k in SOBOL_KEYS if k in bounds and k != "rig.plate_gap"]
    lo = np.array([bounds[k].min for k in dims] + [0.0])
    hi = np.array([bounds[k].max for k in dims] + [MAX_PRELOAD_M])
    gap = bounds["rig.plate_gap"]
    seq = qmc.Sobol(len(lo), scramble=True, seed=0)
    kept: list[tuple[str, dict[str, float]]] = []
    drawn = 0
    with ProcessPoolExecutor(jobs) as pool:
        while len(kept) < n and drawn < 64 * n:
            with warnings.catch_warnings():  # a prefix of the sequence, not a power of 2: fine for a screen
                warnings.simplefilter("ignore", UserWarning)
                batch = qmc.scale(seq.random(max(16, 2 * n)), lo, hi)
            cand = [{k: float(v) for k, v in zip(dims, u[:-1])} for u in batch]
            for values, u, sag in zip(cand, batch, pool.map(sag_of, cand)):
                h = sag - u[-1]
                if gap.min <= h <= gap.max and len(kept) < n:
                    kept.append((f"sobol {drawn}", {**values, "rig.plate_gap": h}))
                drawn += 1
    print(f"Sobol: {len(kept)} of {drawn} candidates rest on the plate with h' inside its bounds", flush=True)
    return kept


def run_all(todo: list[tuple[str, dict[str, float]]], settle: float, record: float, jobs: int) -> list[dict]:
    """The points' maps on ``jobs`` processes, progress printed as they finish."""
    rows: list[dict] = []
    w0 = time.perf_counter()
    with ProcessPoolExecutor(jobs) as pool:
        futs = [pool.submit(run_point, label, v, settle, record) for label, v in todo]
        for i, fut in enumerate(as_completed(futs), 1):
            r = fut.result()
            rows.append(r)
            print(f"[{i}/{len(todo)} {time.perf_counter() - w0:5.0f} s] {line(r)}", flush=True)
    order = {label: i for i, (label, _) in enumerate(todo)}
    return sorted(rows, key=lambda r: order[r["label"]])


def fmt(x: float | None) -> str:
    return "–" if x is None else f"{x:g}"


def line(r: dict) -> str:
    m = met(r)
    return (
        f"{r['label']:34s} cont {fmt(r['continuous_below_hz']):>3s} ½ {fmt(r['half_at_hz']):>3s} "
        f"⅓ {fmt(r['third_at_hz']):>3s} signs {r['sign_26']:+d}/{r['sign_40']:+d} "
        f"cpc26-40 {r['contacts_per_cycle_26_40']:.2f} preload {r['preload_mm']:+.2f} mm  met {sum(m.values())}/5  "
        f"{r['map']}"
    )


def markdown(rows: list[dict], confirmed: list[dict]) -> str:
    head = (
        "| point | values | continuous below | lowest ½ | lowest ⅓ | sign 26 / 40 | contacts/cycle 26–40 | "
        "preload mm | met | map 1–40 Hz |\n|---|---|---|---|---|---|---|---|---|---|"
    )
    out = [head]
    for r in rows + confirmed:
        vals = ", ".join(f"{k.split('.')[-1]} {v:.4g}" for k, v in r["values"].items()) or "shipped"
        tag = " (2+5 s)" if r["record_s"] >= 5 else ""
        out.append(
            f"| {r['label']}{tag} | {vals} | {fmt(r['continuous_below_hz'])} | {fmt(r['half_at_hz'])} | "
            f"{fmt(r['third_at_hz'])} | {r['sign_26']:+d} / {r['sign_40']:+d} | {r['contacts_per_cycle_26_40']:.2f} | "
            f"{r['preload_mm']:+.2f} | {sum(met(r).values())}/5 | `{r['map']}` |"
        )
    return "\n".join(out)


def verdict(rows: list[dict], confirmed: list[dict]) -> str:
    """The answer: does any point meet ½ at 26±2 and ⅓ at 38±2 (and the signs)?"""
    final = {r["label"]: r for r in rows} | {r["label"]: r for r in confirmed}
    both = [r for r in final.values() if met(r)["half_at_hz"] and met(r)["third_at_hz"]]
    signs = [r for r in both if met(r)["sign_26"] and met(r)["sign_40"]]
    best = max(final.values(), key=lambda r: sum(met(r).values()))
    lines = [
        f"points: {len(rows)} screened, {len(confirmed)} confirmed with the protocol's windows",
        f"½ at 26±2 and ⅓ at 38±2: {', '.join(r['label'] for r in both) or 'no point'}"
        f"; with the signs (− at 26, + at 40): {', '.join(r['label'] for r in signs) or 'no point'}",
        f"most targets met: {best['label']} ({sum(met(best).values())}/5): {line(best)}",
        f"any ⅓ at all: {', '.join(r['label'] for r in final.values() if r['third_at_hz'] is not None) or 'none'}",
    ]
    return "\n".join(lines)


def key(point: tuple[str, dict[str, float]], settle: float, record: float) -> str:
    """A run's identity for ``--reuse``: its values and windows."""
    return json.dumps([sorted(point[1].items()), settle, record])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=1, help="worker processes")
    ap.add_argument("--sobol", type=int, default=24, help="space-filling points across the box")
    ap.add_argument("--settle", type=float, default=0.8)
    ap.add_argument("--record", type=float, default=1.2)
    ap.add_argument("--confirm", type=int, default=4, help="near points rerun with the protocol's 2 + 5 s windows")
    ap.add_argument("--only", default="", help="comma-separated bounds keys for the ends (default: all)")
    ap.add_argument("--reuse", action="store_true", help="keep the last run's maps of the same points and windows")
    args = ap.parse_args()
    dest = ROOT / "bench_out"
    w0 = time.perf_counter()
    cache: dict[str, dict] = {}
    if args.reuse and (dest / "contact_bounds.json").exists():
        saved = json.loads((dest / "contact_bounds.json").read_text())
        cache = {
            key((r["label"], r["values"]), r["settle_s"], r["record_s"]): r for r in saved["rows"] + saved["confirmed"]
        }
    only = {k.strip() for k in args.only.split(",") if k.strip()}
    wanted = points(args.sobol, only, args.jobs)
    rows = gather(wanted, args.settle, args.record, args.jobs, cache)
    cands = sorted((r for r in rows if near(r)), key=rank)[: args.confirm]
    print(f"\nconfirming {len(cands)} near points with 2 + 5 s windows", flush=True)
    confirmed = gather([(r["label"], r["values"]) for r in cands], 2.0, 5.0, args.jobs, cache)
    md = markdown(rows, confirmed)
    text = verdict(rows, confirmed)
    print("\n" + md + "\n\n" + text)
    dest.mkdir(exist_ok=True)
    out = {"rows": rows, "confirmed": confirmed, "wall_s": time.perf_counter() - w0, "verdict": text}
    (dest / "contact_bounds.json").write_text(json.dumps(out, indent=1, default=float))
    (dest / "contact_bounds.md").write_text(md + "\n\n" + text + "\n")
    print(f"\n{time.perf_counter() - w0:.0f} s wall; written {dest / 'contact_bounds.json'}")


def gather(wanted: list, settle: float, record: float, jobs: int, cache: dict[str, dict]) -> list[dict]:
    """The maps of ``wanted`` points: the cached ones kept, the rest run."""
    todo = [p for p in wanted if key(p, settle, record) not in cache]
    fresh = (
        {key((r["label"], r["values"]), settle, record): r for r in run_all(todo, settle, record, jobs)} if todo else {}
    )
    return [fresh.get(key(p, settle, record)) or {**cache[key(p, settle, record)], "label": p[0]} for p in wanted]


if __name__ == "__main__":
    main()
