"""How far and how long the contact twin's foot flies after each lift-off, against what a ½ or ⅓ rhythm needs.

    python benchmarks/bench_contact_flight.py                                    # shipped twin, 23 26 30 38 Hz
    python benchmarks/bench_contact_flight.py --set rig.contact_dampratio=0.15 --set rig.plate_gap=0.0065

A 1/n contact rhythm needs the foot to stay off the plate for about n − 1 drive periods after each lift-off. The
foot hangs on the beam (hanging frequency ω_h = √(g/sag) from the static sag) a preload p = sag − h' below the
plate's surface, so a free flight that leaves the plate at v0 lasts T = (2/ω_h)·atan(v0/(ω_h·p)) < π/ω_h. Per
frequency (each held from rest: ramp, ``--settle`` s, then ``--record`` s; noise off; the physics rows, not the load
cells'): contacts per cycle, the flights (normal force zero for longer than 10 % of a period, as the analysis
merges shorter gaps) with their duration, lift-off
velocity and height; the free-flight estimate for the measured v0; and the v0 a flight of (n − 1) periods needs.
``--set key=value`` moves any bounded number (a ``bounds:`` key of ``rod_physical.yaml``, SI).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
G = 9.81


def flights(t: np.ndarray, fn: np.ndarray, z: np.ndarray, min_s: float = 5e-4) -> list[dict]:
    """Each interval with no normal force longer than ``min_s``: start, duration, lift-off velocity, top height."""
    free = fn <= 1e-9
    edges = np.flatnonzero(np.diff(free.astype(int)))
    starts = [i + 1 for i in edges if free[i + 1]]
    out = []
    vz = np.gradient(z, t)
    for s in starts:
        e = s + int(np.argmax(~free[s:])) if (~free[s:]).any() else None
        if e is None:
            continue
        if t[e] - t[s] < min_s:
            continue
        out.append({"t0": t[s], "duration_s": t[e] - t[s], "v0": float(vz[s]), "top_m": float(z[s:e].max())})
    return out


def measure(values: dict[str, float], hz: float, settle: float, record: float) -> dict:
    """One frequency held from rest: flights and contacts of the foot above the plate."""
    from beambench.sim.scenes.contact_regimes import static_sag
    from beambench.sim.scenes.contact_rig import ContactRigSim
    from beambench.sim.scenes.contact_screen import converged_dt, point_twin

    beam, rig = point_twin(values).build()
    sag = static_sag(beam, rig)
    dt = converged_dt(rig)
    scene = ContactRigSim(beam, 90.0, rig.plate_gap, 0.002, rig, "implicitfast", timestep=dt)
    try:
        scene.set_frequency(hz)
        scene.advance_to(settle)
        tr = scene.advance_to(settle + record)
    finally:
        scene.physics.close()
    plate = -(rig.foot_length + rig.plate_gap)
    z = tr.channels["markers"][:, 2, 2] - plate  # the sole's height above the plate's top
    fl = flights(tr.t, tr.channels["force_nt"][:, 0], z, 0.1 / hz)  # shorter gaps: chatter (the analysis merges them)
    omega = math.sqrt(G / sag)
    p = sag - rig.plate_gap
    v0 = np.array([f["v0"] for f in fl]) if fl else np.array([np.nan])
    dur = np.array([f["duration_s"] for f in fl]) if fl else np.array([0.0])
    free_flight = 2 / omega * np.arctan2(v0, omega * p) if p > 0 else np.full_like(v0, np.inf)
    return {
        "hz": hz,
        "sag_mm": sag * 1e3,
        "preload_mm": p * 1e3,
        "f_hang_hz": omega / (2 * math.pi),
        "contacts_per_cycle": len(fl) / (record * hz),
        "flight_ms": 1e3 * float(np.median(dur)),
        "flight_max_ms": 1e3 * float(dur.max()),
        "v0_mm_s": 1e3 * float(np.median(v0)),
        "top_um": 1e6 * float(np.median([f["top_m"] for f in fl])) if fl else 0.0,
        "free_flight_ms": 1e3 * float(np.median(free_flight)),
        "vertical_amplitude_um": 1e6 * float(np.ptp(z) / 2),
        "needed": {n: needed_v0(n, hz, omega, p) for n in (2, 3)},
    }


def needed_v0(n: int, hz: float, omega: float, p: float) -> float:
    """The lift-off velocity (mm/s) a free flight of (n − 1) drive periods needs; inf beyond π/ω_h."""
    span = (n - 1) / hz
    if omega * span >= math.pi:
        return math.inf
    return 1e3 * omega * p * math.tan(omega * span / 2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--freqs", type=float, nargs="+", default=[23.0, 26.0, 30.0, 38.0])
    ap.add_argument("--settle", type=float, default=2.0)
    ap.add_argument("--record", type=float, default=2.0)
    ap.add_argument("--set", action="append", default=[], help="bounds key=value (SI), e.g. rig.plate_gap=0.0065")
    args = ap.parse_args()
    values = {k: float(v) for k, v in (s.split("=", 1) for s in args.set)}
    print(f"point: {values or 'shipped'}")
    print(
        "  Hz  contacts/cycle  flight ms (max)  v0 mm/s  top µm  vert. amp µm  free-flight ms  "
        "v0 for 1/2 | 1/3 (mm/s)  [sag mm, preload mm, f_h Hz]"
    )
    for hz in args.freqs:
        r = measure(values, hz, args.settle, args.record)
        print(
            f"  {hz:4g}  {r['contacts_per_cycle']:14.2f}  {r['flight_ms']:6.1f} ({r['flight_max_ms']:5.1f})  "
            f"{r['v0_mm_s']:7.1f}  {r['top_um']:6.0f}  {r['vertical_amplitude_um']:12.0f}  {r['free_flight_ms']:14.1f}  "
            f"{r['needed'][2]:6.0f} | {r['needed'][3]:6.0f}  [{r['sag_mm']:.2f}, {r['preload_mm']:.2f}, "
            f"{r['f_hang_hz']:.2f}]",
            flush=True,
        )


if __name__ == "__main__":
    main()
