"""Benchmark: the physical twin's candidates — what each physical ingredient does to the contact rig.

    nice -n 15 python benchmarks/bench_physical_twin.py [--out bench_out/physical_twin] [--only NAME,NAME]
        [--settle 2.0] [--record 2.0] [--nthread 2]

Every candidate is the shipped bounded set (``sim_backend/rod_physical.yaml``, model ``rod5g``) with a few
numbers changed (each inside its bounds unless the row says "paper PRB3"), run from rest at 1–40 Hz in one
batched :func:`beambench.sim.scenes.contact_regimes.regime_map` (regimes from the plate's normal force only, noise
off). Columns: the static sag of the foot (from the unloaded shape) and the preload (sag − h'); the map (C
continuous, 1, h = 1/2, t = 1/3, q = 1/4, 2, 3, . irregular, - none); the continuous edge, the lowest 1/2 and 1/3;
the tangential-force sign at 26 and 40 Hz; the self-crossings of the foot's phase-averaged path in the x–z plane
at 26 Hz over its contact period (a figure-8 has 1); and the largest |Ft|/Fn of the contact samples at 26 and
40 Hz (≤ friction by the cone). Writes ``candidates.csv`` and ``candidates.md`` to ``--out``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from beambench.analysis.trajectory import mean_path
from beambench.sim.models.params import BeamParams, load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.scene_params import RigParams
from beambench.sim.scenes.contact_regimes import ContactTwin, regime_map, transitions
from beambench.sim.scenes.contact_rig import build_contact_spec
from beambench.sim.scenes.contact_sweep import contact_sweep
from beambench.sim.settings import SimSettings

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
MODEL = "rod5g"
FREQS = np.arange(1.0, 41.0)


def candidates(base: BeamParams) -> list[tuple[str, str, BeamParams]]:
    """(name, model, parameter set): the ingredients one after another, then one-at-a-time moves of the shipped set."""
    rig = dict(base.rig)

    def with_(beam: dict | None = None, E: float | None = None, **overrides: float) -> BeamParams:
        mat = base.material if E is None else replace(base.material, youngs_modulus=E)
        return replace(base, material=mat, rig={**rig, **overrides}, **(beam or {}))

    bare = {"frame_mass": 0.0, "mass_dx": 0.0, "plate_gap": 0.0055, "friction": 1.0}
    paper = load_params("paper")
    return [
        ("paper PRB3 (k 0.340, b/k 8.5 ms), h' 5.5", "prb3", replace(paper, rig={"plate_gap": 0.0055})),
        ("rod, E 26 MPa, clamp as built (0°), h' 5.5", MODEL, with_(E=26e6, clamp_roll_deg=0.0, **bare)),
        ("rod, E 26 MPa, clamp turned (90°), h' 5.5", MODEL, with_(E=26e6, **bare)),
        ("rod, E 20 MPa, turned, h' 5.5", MODEL, with_(E=20e6, **bare)),
        (
            "rod, E 12 MPa, turned, frame 10 g, h' 6.5",
            MODEL,
            with_(E=12e6, **{**bare, "frame_mass": 0.010, "plate_gap": 0.0065}),
        ),
        (
            "… + load at the corner, dx +10 mm",
            MODEL,
            with_(E=12e6, **{**bare, "frame_mass": 0.010, "plate_gap": 0.0065, "mass_dx": 0.010}),
        ),
        (
            "… + load at the corner, dy +10 mm (no dx)",
            MODEL,
            with_(E=12e6, **{**bare, "frame_mass": 0.010, "plate_gap": 0.0065, "mass_dy": 0.010}),
        ),
        ("shipped set (rod_physical.yaml)", MODEL, base),
        ("shipped, friction 0.5", MODEL, with_(friction=0.5)),
        ("shipped, friction 1.5", MODEL, with_(friction=1.5)),
        ("shipped, beta x0.5", MODEL, with_(beam={"beta": base.beta * 0.5})),
        ("shipped, beta x2", MODEL, with_(beam={"beta": base.beta * 2})),
        ("shipped, h' -0.1 mm", MODEL, with_(plate_gap=rig["plate_gap"] - 1e-4)),
        ("shipped, h' +0.1 mm", MODEL, with_(plate_gap=rig["plate_gap"] + 1e-4)),
    ]


def settled_sag(beam, rig: RigParams, twist_deg: float = 90.0) -> float:
    """Static sag (m) of the foot from its unloaded shape, no plate: settled with every hinge heavily damped
    (the shipped beam's light damping would still ring after seconds; ``contact_sweep.static_sag`` settles 1.5 s)."""
    import mujoco

    m = build_contact_spec(beam, twist_deg, 1.0, rig).compile()
    m.dof_damping[1:] = 0.02
    m.opt.timestep = 2e-4
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    z0 = float(d.site("foot").xpos[2])
    for _ in range(300):
        mujoco.mj_step(m, d, nstep=50)
        d.qpos[0] = d.qvel[0] = 0.0
    return z0 - float(d.site("foot").xpos[2])


def self_crossings(path: np.ndarray) -> int:
    """Proper crossings between non-adjacent segments of a closed polyline (a figure-8 has 1, an ellipse 0)."""
    p = np.asarray(path, float)
    n = len(p) - 1
    count = 0
    for i in range(n):
        a, b = p[i], p[i + 1]
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:
                continue
            c, d = p[j], p[j + 1]

            def side(u, v, w):
                return (v[0] - u[0]) * (w[1] - u[1]) - (v[1] - u[1]) * (w[0] - u[0])

            if side(a, b, c) * side(a, b, d) < 0 and side(c, d, a) * side(c, d, b) < 0:
                count += 1
    return count


def measure(name: str, model: str, params: BeamParams, settle: float, record: float, nthread: int | None) -> dict:
    """One candidate's row (see the module docstring)."""
    t0 = time.perf_counter()
    bm = make_beam_model(model, params)
    rig = RigParams.with_overrides(params.rig)
    sag = settled_sag(bm, rig)
    sim = SimSettings(settle_s=settle, record_s=record, nthread=nthread)
    df = regime_map(FREQS, sim, ContactTwin(model=model, params=params))
    lab = dict(zip(df.frequency_hz, df.regime))
    sign = dict(zip(df.frequency_hz, df.tangential_sign))
    tr = transitions(df.frequency_hz, df.regime)
    # the foot's path and forces at 26 and 40 Hz (the same runs from rest)
    sw = contact_sweep(bm, [26.0, 40.0], sim, gap_m=rig.plate_gap, rig=rig)
    k = {"1/2": 2, "1/3": 3, "1/4": 4}.get(lab[26.0], 1)
    path = mean_path(sw.t, sw.foot[0][:, [0, 2]] * 1e3, k / 26.0, bins=40 * k)
    ratio = 0.0
    for i in range(2):
        normal, _ = sw.contact[i]
        tang, _ = sw.motion[i]
        on = normal > 0.02
        if on.any():
            ratio = max(ratio, float(np.max(np.abs(tang[on]) / normal[on])))
    return {
        "candidate": name,
        "model": model,
        "sag_mm": round(sag * 1e3, 2),
        "gap_mm": round(rig.plate_gap * 1e3, 2),
        "preload_mm": round((sag - rig.plate_gap) * 1e3, 2),
        "map_1_40": "".join(CODE.get(lab[f], "?") for f in FREQS),
        "continuous_below_hz": tr["continuous_below_hz"],
        "half_at_hz": tr["half_at_hz"],
        "third_at_hz": tr["third_at_hz"],
        "sign_26": int(sign[26.0]),
        "sign_40": int(sign[40.0]),
        "crossings_26": self_crossings(path),
        "max_ft_over_fn": round(ratio, 3),
        "friction": rig.friction,
        "wall_s": round(time.perf_counter() - t0, 1),
    }


def session_paths(path: str, frequencies: tuple[float, ...] = (16.0, 26.0, 40.0)) -> list[dict]:
    """The shipped sweep's figure-8 check on a recorded session: per step at ``frequencies``, the self-crossings
    of the foot's phase-averaged path in the world x–z plane (the mocap's, with its noise) over 1, 2 and 3 drive
    periods (read the one of the step's contact period from ``beambench analyze``'s regime)."""
    from beambench.acquisition.streams import CONTACT_MARKERS
    from beambench.sinks.session_file.reader import read_session

    s = read_session(path)
    mocap = s.streams["mocap"]
    t_ns = mocap.host_time_ns.astype(np.int64)
    foot = mocap.columns["data"][:, CONTACT_MARKERS.index("foot")]
    out = []
    for row in s.steps.itertuples():
        f = float(row.frequency_hz)
        if f not in frequencies or int(row.t_settled_ns) < 0:
            continue
        sel = (t_ns >= int(row.t_settled_ns)) & (t_ns < int(row.t_end_ns))
        t, xz = t_ns[sel] / 1e9, foot[sel][:, [0, 2]] * 1e3
        res = {"frequency_hz": f}
        for k in (1, 2, 3):
            res[f"crossings_{k}T"] = self_crossings(mean_path(t, xz, k / f, bins=30 * k))
        res["z_range_mm"] = round(float(np.ptp(xz[:, 1])), 2)
        out.append(res)
    return out


def markdown(df: pd.DataFrame) -> str:
    """A Markdown table of ``df`` (no extra dependency)."""
    lines = ["| " + " | ".join(df.columns) + " |", "|" + "---|" * len(df.columns)]
    lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench_out/physical_twin")
    ap.add_argument("--only", default="", help="comma-separated substrings of candidate names")
    ap.add_argument("--settle", type=float, default=2.0)
    ap.add_argument("--record", type=float, default=2.0)
    ap.add_argument("--nthread", type=int, default=None)
    ap.add_argument("--session", default="", help="only the figure-8 check on a recorded contact sweep")
    args = ap.parse_args(argv)
    if args.session:
        print(markdown(pd.DataFrame(session_paths(args.session))))
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    base = load_params("physical", model="rod")
    rows = []
    for name, model, params in candidates(base):
        if args.only and not any(s in name for s in args.only.split(",")):
            continue
        rows.append(measure(name, model, params, args.settle, args.record, args.nthread))
        print(rows[-1], flush=True)
        df = pd.DataFrame(rows)
        df.to_csv(out / "candidates.csv", index=False)
        (out / "candidates.md").write_text(markdown(df))
    print(markdown(pd.DataFrame(rows)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
