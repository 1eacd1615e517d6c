"""Can the physical strip legs carry the walker? Geometry variants of the physical twin's walker.

    python benchmarks/bench_walker_legs.py [--out DIR] [--quick]

For each variant of the walker's unknown geometry (legs sideways or hanging down, foot length, where the motor
sits along the platform, foot mass, friction, spin sense), on the physical set's legs (rod5g,
sim_backend/rod_physical.yaml):

- ``stand_mm``: the body's height 2 s after the preroll with the motor off, against its clamp height
  (``clamp_mm``: leg drop + foot); ``sole_n`` the static load per sole (moment balance about the wheels) and
  ``torsion_limit_n`` = GJ/(L·l_foot), the load a sideways leg's rigid foot stands under (an inverted pendulum on
  the strip's torsion; not the limit of a hanging leg);
- ``v23``/``v65`` (mm/s) and ``z23``/``z65`` (mean body height, mm) at 23 and 65 Hz, steady
  (:func:`beambench.sim.scenes.walker_batch.steady_speeds`: settle 2 s after the ramp, record 1 s);
- ``v23_half``/``v65_half``: the same at half the timestep — a twin whose speeds move with the timestep predicts
  nothing.

Writes ``walker_legs.csv`` and prints a Markdown table (docs/contact-twin.md keeps the one measured). One thread.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from beambench.common.resources import user_dir
from beambench.sim.models.params import load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.scene_params import WalkerParams
from beambench.sim.scenes.walker import WalkerSim, sole_load
from beambench.sim.scenes.walker_batch import steady_speeds
from beambench.sim.settings import SimSettings

VARIANTS: list[tuple[str, dict[str, float]]] = [
    ("shipped: sideways, foot 66.5 mm, 20 g", {}),
    ("sideways, foot 10 mm", {"foot_length": 0.010}),
    ("sideways, foot 35 mm, motor 100 mm back", {"foot_length": 0.035, "motor_x": -0.10}),
    ("sideways, foot 20 mm, motor 150 mm back", {"foot_length": 0.020, "motor_x": -0.15}),
    ("sideways, foot 66.5 mm, motor 150 mm back", {"motor_x": -0.15}),
    ("legs 60° down, foot 20 mm, 3 g", {"leg_droop_deg": 60, "foot_length": 0.020, "foot_mass": 0.003}),
    ("hanging, foot 10 mm, 3 g, spin +", {"leg_droop_deg": 90, "foot_length": 0.010, "foot_mass": 0.003, "spin": 1}),
    ("hanging, foot 10 mm, 3 g, spin −", {"leg_droop_deg": 90, "foot_length": 0.010, "foot_mass": 0.003}),
    (
        "hanging, foot 10 mm, 10 g, μ 0.5",
        {"leg_droop_deg": 90, "foot_length": 0.010, "foot_mass": 0.010, "friction": 0.5},
    ),
]
QUICK = [0, 1, 6]


def _static(beam, wp: WalkerParams) -> dict[str, float]:
    sim = WalkerSim(beam, 90.0, wp)
    try:
        sole = sole_load(sim.physics.model)
        body = sim.advance_to(2.0).channels["markers"][:, 0, 2]
    finally:
        sim.physics.close()
    return {"sole_n": sole, "stand_mm": 1e3 * float(body[-1])}


def measure(label: str, overrides: dict[str, float], half: bool) -> dict[str, object]:
    params = load_params("physical", model="rod")
    beam = make_beam_model("rod5g", params)
    wp = WalkerParams.with_overrides({**params.walker, **overrides})
    t0 = time.perf_counter()
    row: dict[str, object] = {"variant": label}
    row["clamp_mm"] = 1e3 * (params.length * np.sin(np.radians(wp.leg_droop_deg)) + wp.foot_length)
    row.update(_static(beam, wp))
    row["torsion_limit_n"] = beam.torsion_stiffness() / wp.foot_length
    sim = SimSettings(settle_s=2.0, record_s=1.0, nthread=1)
    speed, height = steady_speeds(beam, (23.0, 65.0), wp, settings=sim)
    row.update(v23=speed[0], v65=speed[1], z23=height[0], z65=height[1])
    if half:
        speed2, _ = steady_speeds(beam, (23.0, 65.0), wp, settings=sim.replace(timestep=wp.timestep / 2))
        row.update(v23_half=speed2[0], v65_half=speed2[1])
    row["wall_s"] = time.perf_counter() - t0
    return row


def _markdown(df: pd.DataFrame) -> str:
    lines = ["| " + " | ".join(df.columns) + " |", "|" + "---|" * len(df.columns)]
    lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None, help="output folder (default: the per-user bench folder)")
    ap.add_argument("--quick", action="store_true", help="three variants, no half-timestep runs")
    args = ap.parse_args()
    out = args.out or user_dir("bench") / "walker_legs"
    out.mkdir(parents=True, exist_ok=True)
    chosen = [VARIANTS[i] for i in QUICK] if args.quick else VARIANTS
    rows = []
    for label, overrides in chosen:
        rows.append(measure(label, overrides, half=not args.quick))
        print(f"{label}: {rows[-1]}", file=sys.stderr, flush=True)
    table = pd.DataFrame(rows)
    table.to_csv(out / "walker_legs.csv", index=False)
    print(_markdown(table.round(1)))
    print(f"\nwritten: {out / 'walker_legs.csv'}", file=sys.stderr)


if __name__ == "__main__":
    main()
