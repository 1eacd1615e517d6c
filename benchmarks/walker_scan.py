"""Quick scan of the shipped walker's unknowns: steady speeds at a few frequencies for override sets.

    python benchmarks/walker_scan.py '[{"leg_roll_deg": 60, "leg_mount_deg": 5}, {"motor_flat": 2}]'

Each set overrides the physical set's walker block (``sim_backend/rod_physical.yaml``, rod5g legs); one line per
set: the speeds (mm/s, + away from the cart) at 15, 23, 30, 50, 65 Hz from a settled robot (settle 2 s, record
1 s: quicker than the 3 s / 1.5 s of the twin's evidence, the 65 Hz speed is still rising then), the range of the
body's mean height (mm) and the wall time. Single thread: run at most one per core.
"""

from __future__ import annotations

import argparse
import json
import time

FREQUENCIES = (15.0, 23.0, 30.0, 50.0, 65.0)


def main() -> None:
    from beambench.sim.models.params import load_params
    from beambench.sim.models.registry import make_beam_model
    from beambench.sim.scene_params import WalkerParams
    from beambench.sim.scenes.walker_batch import steady_speeds
    from beambench.sim.settings import SimSettings

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sets", help="JSON list of walker-block overrides, one dict per set")
    ap.add_argument("--settle", type=float, default=2.0, help="s after the ramp (default 2)")
    args = ap.parse_args()
    physical = load_params("physical", model="rod")
    beam = make_beam_model("rod5g", physical)
    settings = SimSettings(settle_s=args.settle, record_s=1.0, nthread=1)
    for overrides in json.loads(args.sets):
        t0 = time.perf_counter()
        wp = WalkerParams.with_overrides({**(physical.walker or {}), **overrides})
        speed, height = steady_speeds(beam, FREQUENCIES, wp, settings=settings)
        speeds = " ".join(f"{f:g}:{v:+.0f}" for f, v in zip(FREQUENCIES, speed, strict=True))
        wall = time.perf_counter() - t0
        print(
            f"{json.dumps(overrides)} {speeds} height {min(height):.0f}-{max(height):.0f} mm {wall:.0f} s", flush=True
        )


if __name__ == "__main__":
    main()
