"""Benchmark: the contact scene's cost per physics step under MuJoCo options that might not change its answers.

    python benchmarks/bench_contact_step.py                  # 20 and 30 Hz, 40 000 steps, median of 5
    python benchmarks/bench_contact_step.py --hz 26 --steps 20000 --repeats 3

The shipped contact sweep's scene (``protocols/contact_sweep.yaml``: rod5g, physical, 5e-5 s) is driven 3 s into
each frequency; from that state every option runs the same ``--steps`` steps through the rig's own stepping
(``mujoco.rollout``), interleaved, ``--repeats`` times: CPU µs per step (the thread's CPU time: compare the ratios
on a loaded machine), the change against the shipped options, and whether the trajectory is the same (the largest
difference of the plate force over the run, N; 0 is bit for bit). An option that changes the trajectory must
keep the convergence criterion on the whole sweep (``bench_contact_speed.py``) to be shipped. Also prints
MuJoCo's own per-stage timers (``data.timer``, from a plain ``mj_step`` loop: their absolute values include the
timers' overhead).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def options(shipped_flags: int) -> dict[str, dict[str, int | float]]:
    """Each candidate: ``MjOption`` fields set on top of the shipped scene's (PGS, unused stages skipped)."""
    island = int(mujoco.mjtDisableBit.mjDSBL_ISLAND)
    newton = int(mujoco.mjtSolver.mjSOL_NEWTON)
    return {
        "shipped": {},
        "Newton solver": {"solver": newton},
        "Newton, every stage on (MuJoCo's defaults)": {"solver": newton, "disableflags": 0},
        "Newton, islands on": {"solver": newton, "disableflags": shipped_flags & ~island},
        "CG solver": {"solver": int(mujoco.mjtSolver.mjSOL_CG)},
        "dense Jacobian": {"jacobian": int(mujoco.mjtJacobian.mjJAC_DENSE)},
        "sparse Jacobian": {"jacobian": int(mujoco.mjtJacobian.mjJAC_SPARSE)},
        "Newton, 3 iterations": {"solver": newton, "iterations": 3},
        "Newton, 5 line-search iterations": {"solver": newton, "ls_iterations": 5},
        "PGS, tolerance 1e-6": {"tolerance": 1e-6},
        "PGS, 20 iterations": {"iterations": 20},
    }


def stage_timers(scene, snap, n: int) -> dict[str, float]:
    """MuJoCo's per-stage timers (µs per step) over ``n`` plain ``mj_step`` calls from ``snap``."""
    m, d = scene.physics.model, scene.physics.data
    scene.restore(snap)
    ctrl, _ = scene._plan(n, scene.physics.timestep)
    for i in range(len(d.timer)):
        d.timer[i].duration, d.timer[i].number = 0.0, 0
    for k in range(n):
        d.ctrl[:] = ctrl[k]
        mujoco.mj_step(m, d)
    out = {}
    for name, t in mujoco.mjtTimer.__members__.items():
        if int(t) < len(d.timer) and d.timer[int(t)].number:
            out[name.removeprefix("mjTIMER_").lower()] = d.timer[int(t)].duration / n * 1e6
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hz", type=float, nargs="+", default=[20.0, 30.0])
    ap.add_argument("--steps", type=int, default=40_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    from beambench.acquisition.protocol.schema import load_protocol
    from beambench.backends.sim import build_scene
    from beambench.session.slices import sim_slice

    protocol, _ = load_protocol(ROOT / "protocols" / "contact_sweep.yaml")
    scene = build_scene(sim_slice(protocol))
    opt = scene.physics.model.opt
    shipped = {
        k: getattr(opt, k) for k in ("disableflags", "jacobian", "solver", "iterations", "ls_iterations", "tolerance")
    }
    variants = options(int(opt.disableflags))
    for hz in args.hz:
        scene.set_frequency(hz)
        scene.advance_to(scene.physics.time + 3.0)
        snap = scene.snapshot()
        cost: dict[str, list[float]] = {name: [] for name in variants}
        diff: dict[str, float] = {}
        reference = None
        for rep in range(args.repeats):
            for name, change in variants.items():
                for k, v in {**shipped, **change}.items():
                    setattr(opt, k, v)
                scene.restore(snap)
                c0 = time.thread_time()
                rows = scene.advance_to(scene.physics.time + args.steps * scene.physics.timestep)
                cost[name].append((time.thread_time() - c0) / len(rows) * 1e6)
                if rep == 0:
                    force = rows.channels["force_nt"]
                    reference = force if reference is None else reference
                    diff[name] = float(np.abs(force - reference).max())
        for k, v in shipped.items():
            setattr(opt, k, v)
        base = float(np.median(cost["shipped"]))
        print(f"--- {hz:g} Hz, dt {scene.physics.timestep:g} s, {args.steps} steps, median of {args.repeats}")
        for name in variants:
            med = float(np.median(cost[name]))
            same = "bit for bit" if diff[name] == 0 else f"differs (max |dF| {diff[name]:.2g} N)"
            print(f"{name:36s} {med:6.2f} us/step ({med / base - 1:+6.1%})  {same}")
        timers = stage_timers(scene, snap, min(args.steps, 20_000))
        print("MuJoCo timers (us/step):", ", ".join(f"{k} {v:.2f}" for k, v in timers.items()))


if __name__ == "__main__":
    main()
