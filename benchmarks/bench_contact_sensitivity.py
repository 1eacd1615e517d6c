"""Benchmark: which unknowns of the contact-rig twin move its regime map.

    python benchmarks/bench_contact_sensitivity.py [--params contact_paper] [--out bench_out/contact_sensitivity]
        [--start 2 --stop 44 --step 2] [--settle 1.5] [--record 2.0] [--noise] [--only U1,U2] [--nthread N]

One unknown at a time, each at two values around the parameter set (default: the shipped calibrated
``prb3_contact_paper``): stiffness scale (k and k_twist), damping scale (b and b_twist), the gap h' (from the
unloaded foot), the foot mass, the contact time constant, friction, the load's offset from the sole along
the stage travel, and the clamp orientation (section turned 90° at the clamp); then the stiffness
and the load frame's own mass at the same interference (sag − gap), the load's offset along y, a stuck foot
(friction 6) and a compliant sole (``--only 'compliant sole,friction'`` runs a subset; ``_match_sag`` rows move
the gap with the sag so the interference stays the base's). For each: the continuous
edge (the lowest step that is not ``continuous``, when the map starts continuous:
:func:`~beambench.sim.scenes.contact_regimes.transitions`), the lowest ``1/2``, the lowest ``1/3`` and
the map as a string (C continuous, 1, h = 1/2, t = 1/3, q = 1/4, 2, 3, . irregular, - none). Regimes come
from the plate's normal force only (:func:`beambench.sim.scenes.contact_regimes.regime_map`).

Writes ``sensitivity.csv`` and ``sensitivity.md`` (a Markdown table) to ``--out`` and prints the table.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CODE = {
    "continuous": "C",
    "1": "1",
    "1/2": "h",
    "1/3": "t",
    "1/4": "q",
    "2": "2",
    "3": "3",
    "irregular": ".",
    "none": "-",
}


def variations(base_rig) -> list[tuple[str, str, dict, dict]]:
    """(unknown, value label, beam scale factors, rig overrides) — two values per unknown."""
    g = base_rig.plate_gap
    fm = base_rig.foot_mass
    return [
        ("base", "", {}, {}),
        ("stiffness scale", "×0.8", {"k": 0.8}, {}),
        ("stiffness scale", "×1.25", {"k": 1.25}, {}),
        ("damping scale", "×0.5", {"b": 0.5}, {}),
        ("damping scale", "×2", {"b": 2.0}, {}),
        ("gap h'", f"{(g - 3e-4) * 1e3:.2f} mm", {}, {"plate_gap": g - 3e-4}),
        ("gap h'", f"{(g + 3e-4) * 1e3:.2f} mm", {}, {"plate_gap": g + 3e-4}),
        ("foot mass", f"{(fm - 3e-3) * 1e3:.0f} g", {}, {"foot_mass": fm - 3e-3}),
        ("foot mass", f"{(fm + 3e-3) * 1e3:.0f} g", {}, {"foot_mass": fm + 3e-3}),
        ("contact time constant", "0.5 ms", {}, {"contact_timeconst": 5e-4}),
        ("contact time constant", "2 ms", {}, {"contact_timeconst": 2e-3}),
        ("friction", "0.25", {}, {"friction": 0.25}),
        ("friction", "1.0", {}, {"friction": 1.0}),
        ("mass offset", "+10 mm", {}, {"mass_dx": base_rig.mass_dx + 0.01}),
        ("mass offset", "−10 mm", {}, {"mass_dx": base_rig.mass_dx - 0.01}),
        ("clamp orientation", "turned 90°", {}, {"clamp_roll_deg": 90.0}),
        ("clamp orientation", "turned 90°, gap −sag diff", {}, {"clamp_roll_deg": 90.0, "_match_sag": 1.0}),
        # at the same interference (docs/contact-twin.md, "What moves the continuous edge")
        ("stiffness at same interference", "×0.8", {"k": 0.8}, {"_match_sag": 1.0}),
        ("stiffness at same interference", "×1.25", {"k": 1.25}, {"_match_sag": 1.0}),
        ("frame mass at same interference", "5 g", {}, {"frame_mass": 0.005, "_match_sag": 1.0}),
        ("frame mass at same interference", "10 g", {}, {"frame_mass": 0.010, "_match_sag": 1.0}),
        (
            "mass offset along y",
            "+10 mm, same interference",
            {},
            {"mass_dy": base_rig.mass_dy + 0.01, "_match_sag": 1.0},
        ),
        (
            "mass offset along y",
            "−10 mm, same interference",
            {},
            {"mass_dy": base_rig.mass_dy - 0.01, "_match_sag": 1.0},
        ),
        ("friction", "6 (foot stuck)", {}, {"friction": 6.0}),
        (
            "compliant sole",
            "300 N/m, 0.5 N·s/m",
            {},
            {"sole_stiffness": 300.0, "sole_damping": 0.5, "sole_mass": 3e-4},
        ),
        (
            "compliant sole",
            "1500 N/m, 0.5 N·s/m, 20 µm travel",
            {},
            {"sole_stiffness": 1500.0, "sole_damping": 0.5, "sole_mass": 3e-4, "sole_travel": 2e-5},
        ),
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default="contact_paper")
    ap.add_argument("--out", type=Path, default=ROOT / "bench_out" / "contact_sensitivity")
    ap.add_argument("--start", type=float, default=2.0)
    ap.add_argument("--stop", type=float, default=44.0)
    ap.add_argument("--step", type=float, default=2.0)
    ap.add_argument("--settle", type=float, default=1.5)
    ap.add_argument("--record", type=float, default=2.0)
    ap.add_argument("--noise", action="store_true")
    ap.add_argument("--only", default="", help="comma-separated unknowns to run (default: all), e.g. 'frame mass'")
    ap.add_argument("--nthread", type=int, default=None, help="MuJoCo threads (default: all cores)")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    import numpy as np
    import pandas as pd

    from beambench.sim.models.params import load_params
    from beambench.sim.models.registry import make_beam_model
    from beambench.sim.scene_params import RigParams
    from beambench.sim.scenes.contact_regimes import ContactTwin, regime_map, static_sag, transitions
    from beambench.sim.settings import SimSettings

    base = load_params(args.params, "prb3")
    base_rig = RigParams.with_overrides(base.rig)
    sag0 = static_sag(make_beam_model("prb3", base), base_rig)
    freqs = np.arange(args.start, args.stop + 1e-9, args.step)
    rows = []
    t_all = time.perf_counter()
    only = {w.strip() for w in args.only.split(",") if w.strip()}
    for unknown, label, scale, rig in variations(base_rig):
        if only and unknown not in only and unknown != "base":
            continue
        p = replace(
            base,
            k=base.k * scale.get("k", 1.0),
            k_twist=base.k_twist * scale.get("k", 1.0),
            b=base.b * scale.get("b", 1.0),
            b_twist=base.b_twist * scale.get("b", 1.0),
        )
        over = {k: v for k, v in rig.items() if not k.startswith("_")}
        if rig.get("_match_sag"):  # same preload (sag − gap) as the base
            sag = static_sag(make_beam_model("prb3", p), RigParams.with_overrides({**base.rig, **over}))
            over["plate_gap"] = base_rig.plate_gap + (sag - sag0)
        t0 = time.perf_counter()
        sim = SimSettings(settle_s=args.settle, record_s=args.record, noise=args.noise, nthread=args.nthread)
        df = regime_map(freqs, sim, ContactTwin(params=p, rig_overrides=over))
        # the continuous edge: the lowest step that is not continuous (NaN: the map does not start continuous)
        tr = {k: math.nan if v is None else v for k, v in transitions(df.frequency_hz, df.regime).items()}
        rows.append(
            {
                "unknown": unknown,
                "value": label or "(parameter set)",
                "continuous_below_hz": tr["continuous_below_hz"],
                "half_at_hz": tr["half_at_hz"],
                "third_at_hz": tr["third_at_hz"],
                "map": "".join(CODE.get(r, "?") for r in df.regime),
                "tangential_sign": "".join({1: "+", -1: "-", 0: "0"}[int(s)] for s in df.tangential_sign),
                "wall_s": time.perf_counter() - t0,
            }
        )
        r = rows[-1]
        print(
            f"{unknown:22s} {r['value']:28s} cont {r['continuous_below_hz']:4g}  1/2 {r['half_at_hz']:4g}  "
            f"1/3 {r['third_at_hz']:4g}  {r['map']}",
            flush=True,
        )
    table = pd.DataFrame(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out / "sensitivity.csv", index=False)
    head = f"map at {freqs[0]:g}–{freqs[-1]:g} Hz step {args.step:g} (params {args.params}, noise {args.noise})"
    md = [
        "| unknown | value | continuous ≤ Hz | lowest 1/2 Hz | lowest 1/3 Hz | " + head + " |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        md.append(
            f"| {r['unknown']} | {r['value']} | {r['continuous_below_hz']:g} | {r['half_at_hz']:g} | "
            f"{r['third_at_hz']:g} | `{r['map']}` |"
        )
    (args.out / "sensitivity.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    print(f"wall {time.perf_counter() - t_all:.0f} s")


if __name__ == "__main__":
    main()
