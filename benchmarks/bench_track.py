"""Benchmark: speed tracking on the sim walker against its goals (each segment's RMS error within tolerance after
settling, direction within 1.5 s, within the frequency limit), each from one run.

    python benchmarks/bench_track.py [--out DIR] [--mismatch foot_mass=0.0022] [--profiles] [--ramp 100]

1. ``protocols/walker_track.yaml`` as shipped (``map: twin``: its own sweep first, then the profile).
2. A map from a *different* twin (``--mismatch``: a walker parameter changed, default the foot 10 % heavier): its
   sweep (the shipped protocol's) with that parameter set, then the same profile on the calibrated twin with
   feed-forward alone and with feedback.

3. ``--profiles``: more profiles on run 1's map (:data:`PROFILES`: steps up and down, stops, through zero, backward),
   with how many segments settle within 1 s.
4. ``--ramp R``: the shipped profile and :data:`PROFILES` on run 1's map with the twin's motor ramping at R turn/s²
   (its ``vel_ramp_rate``; the shipped twin's is the walker drive's, 200 in calibration/rig.yaml): how much of the
   settling is the motor's ramp.

Per run and segment: target, mean speed, RMS error after ``track.settle_s`` against its tolerance (15 % of
|target|, 10 mm/s below 60 mm/s), settling and direction times, highest frequency; a verdict per goal. Writes
``tracking.png`` (run 1) and ``tracking_ff_vs_fb.png`` (run 2) into ``--out`` (default: a temporary folder).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def _run(text: str, path: Path):
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.analysis.session_analysis import analyze_session
    from beambench.session.run import run_session
    from beambench.sinks.session_file.reader import read_session

    t0 = time.perf_counter()
    result = run_session(parse_protocol(text), text, "sim", path, show_progress=False)
    wall = time.perf_counter() - t0
    if result.status != "completed":
        raise SystemExit(f"{path.name}: run {result.status}: {result.message}")
    return analyze_session(read_session(path)).track, wall


PROFILES = {  # (target mm/s, hold s): within the shipped map's reach (forward to ~+120, backward to ~-75 mm/s)
    "slow-downs and a stop": [(100, 4), (0, 3), (60, 3), (90, 3), (30, 3)],
    "through zero and backward": [(-40, 4), (80, 4), (-20, 4), (0, 3), (50, 3), (-30, 3)],
    "top speed to a stop and back": [(60, 4), (120, 3), (0, 3), (120, 3), (30, 3)],
}


def _profiles(
    shipped: dict, map_path: Path, out: Path, limit: float, params: str | None = None, extra: dict | None = None
) -> None:
    """Each of ``extra`` and :data:`PROFILES` on the map of run 1 (the twin's parameter set ``params``, default the
    shipped one); per segment its settling time, the count within 1 s."""
    for name, profile in {**(extra or {}), **PROFILES}.items():
        p = {**shipped, "track": {**shipped["track"], "map": str(map_path)}}
        if params is not None:
            p["sim"] = {**shipped["sim"], "params": params}
        p["track"]["segments"] = [{"speed_mm_s": v, "hold_s": h} for v, h in profile]
        tag = f"{params or 'profile'}_{len(profile)}_{profile[0][0]}"
        track, wall = _run(yaml.safe_dump(p), out / f"{tag}.h5")
        _verdict(f"{params or 'profile'}: {name}", track, limit, wall)
        quick = sum(s["settling_s"] <= 1.0 for s in track.segments)
        print(f" settled within 1 s: {quick} of {len(track.segments)} segments")


def _verdict(name: str, track, limit_hz: float, wall: float) -> bool:
    print(f"\n{name}  ({wall:.0f} s wall)")
    print(" seg  target   mean    RMS  tol  settle  direction  max Hz  goal")
    ok_all = True
    for s in track.segments:
        ok = s["speed_error_rms_mm_s"] <= s["tolerance_mm_s"] and s["max_frequency_hz"] <= limit_hz
        if s["target_speed_mm_s"] != 0:
            ok &= s["direction_s"] <= 1.5 if math.isfinite(s["direction_s"]) else False
        ok_all &= ok
        print(
            f" {s['step']:3d} {s['target_speed_mm_s']:+7.1f} {s['mean_speed_mm_s']:+7.1f} {s['speed_error_rms_mm_s']:6.1f} "
            f"{s['tolerance_mm_s']:4.0f} {s['settling_s']:7.2f} {s['direction_s']:10.2f} {s['max_frequency_hz']:7.1f}  "
            f"{'met' if ok else 'MISSED'}"
        )
    print(
        f" goals (RMS <= tolerance after settling, direction <= 1.5 s, <= {limit_hz:g} Hz): {'met' if ok_all else 'MISSED'}"
    )
    return ok_all


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--mismatch", default="foot_mass=0.0022", help="walker parameter of the other twin, NAME=VALUE")
    ap.add_argument("--profiles", action="store_true", help="also run PROFILES on run 1's map")
    ap.add_argument("--ramp", type=float, default=None, help="also run them with the twin's motor ramp (turn/s²)")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_track_"))
    out.mkdir(parents=True, exist_ok=True)
    user = out / "user"
    (user / "sim_backend").mkdir(parents=True, exist_ok=True)
    os.environ["BEAMBENCH_USER_DIR"] = str(user)  # the other twin's parameter set lives here
    from beambench.analysis.figures.speed_tracking import draw_tracking
    from beambench.session.track_map import map_from_session

    shipped = yaml.safe_load((ROOT / "protocols" / "walker_track.yaml").read_text())
    limit = float(shipped["limits"]["max_frequency_hz"])
    own, wall = _run(yaml.safe_dump(shipped), out / "own.h5")
    ok = _verdict("walker_track as shipped (map: twin)", own, limit, wall)
    draw_tracking([own], ["beambench run walker_track (map: twin)"], out / "tracking.png")
    if args.profiles:
        _profiles(shipped, out / "own_map.h5", out, limit)

    from beambench.sim.models.registry import model_family

    family = model_family(shipped["sim"]["model"])
    if args.ramp is not None:
        params = yaml.safe_load((ROOT / "sim_backend" / f"{family}_{shipped['sim']['params']}.yaml").read_text())
        params.update(name="ramp", walker={**params.get("walker", {}), "vel_ramp_rate": args.ramp})
        (user / "sim_backend" / f"{family}_ramp.yaml").write_text(yaml.safe_dump(params))
        shipped_profile = {"shipped": [(s["speed_mm_s"], s["hold_s"]) for s in shipped["track"]["segments"]]}
        print(f"\nthe twin's motor ramping at {args.ramp:g} turn/s²:")
        _profiles(shipped, out / "own_map.h5", out, limit, "ramp", shipped_profile)

    name, value = args.mismatch.split("=")
    params = yaml.safe_load((ROOT / "sim_backend" / f"{family}_{shipped['sim']['params']}.yaml").read_text())
    params.update(name="other_twin", walker={**params.get("walker", {}), name: float(value)})
    (user / "sim_backend" / f"{family}_other_twin.yaml").write_text(yaml.safe_dump(params))
    sweep = {k: v for k, v in shipped.items() if k != "track"}
    sweep["sim"] = {**shipped["sim"], "params": "other_twin"}
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.session.run import run_session

    text = yaml.safe_dump(sweep)
    if run_session(parse_protocol(text), text, "sim", out / "other_map.h5", show_progress=False).status != "completed":
        raise SystemExit("the other twin's sweep did not complete")
    other = map_from_session(out / "other_map.h5")
    print(f"\nother twin ({args.mismatch}) map reach: {other.reach(limit)}")
    results = []
    for feedback in (False, True):
        p = {**shipped, "track": {**shipped["track"], "map": str(out / "other_map.h5")}}
        p["track"]["control"] = {**shipped["track"].get("control", {}), "feedback": feedback}
        track, wall = _run(yaml.safe_dump(p), out / f"other_{'fb' if feedback else 'ff'}.h5")
        label = "with feedback" if feedback else "feed-forward alone"
        ok_run = _verdict(f"map from the other twin, {label}", track, limit, wall)
        ok &= ok_run if feedback else True
        results.append(track)
    draw_tracking(
        results,
        [f"map from a twin with {args.mismatch}: feed-forward alone", "same map: with feedback"],
        out / "tracking_ff_vs_fb.png",
    )
    print(f"\nfigures: {out / 'tracking.png'}, {out / 'tracking_ff_vs_fb.png'}")
    print(f"verdict: {'goals met' if ok else 'goals MISSED'} (own map with feedback; other map with feedback)")


if __name__ == "__main__":
    main()
