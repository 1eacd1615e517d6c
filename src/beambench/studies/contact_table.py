"""The timestep table of the contact scene (``sim_backend/contact_table.csv``, read by :mod:`beambench.sim.selection`
for ``scene="contact"``) and the contact timing goals — measured by ``benchmarks/bench_models.py``.

:func:`measure_contact_table`: per frequency, integrator and timestep, the foot-path RMS error against the same
model at :data:`REFERENCE_DT`, the contacts per cycle and the wall time per 10 s simulated (batched runs of
:func:`beambench.sim.scenes.contact_sweep.contact_sweep`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from beambench.common.types import Floats
from beambench.sim.models.beam import BeamModel
from beambench.sim.models.registry import beam_model
from beambench.sim.scene_params import RigParams
from beambench.sim.scenes.contact_sweep import contact_sweep
from beambench.sim.settings import SimSettings

REFERENCE_DT = 2.5e-5
IRREGULAR_MM = 0.05  # fine runs this far from the reference (foot path RMS) mark an irregular regime


def time_contact(
    beam: BeamModel | str,
    frequency: float,
    timestep: float,
    seconds: float = 10.0,
    repeats: int = 3,
    gap_m: float = 0.001,
    integrator: str = "implicitfast",
) -> tuple[float, float]:
    """(median wall s, median thread-CPU s) of stepping ``seconds`` simulated of one contact run on one thread."""
    walls, cpus = [], []
    sim = SimSettings(settle_s=0.0, record_s=seconds, integrator=integrator, timestep=(timestep,), nthread=1)
    for _ in range(repeats):
        timing: dict = {}
        contact_sweep(beam, [frequency], sim, gap_m=gap_m, timing=timing)
        walls.append(timing["wall"])
        cpus.append(timing["cpu"])
    return float(np.median(walls)), float(np.median(cpus))


TABLE_FREQUENCIES = (
    1,
    2,
    3,
    4,
    5,
    6,
    8,
    10,
    12,
    15,
    17,
    20,
    22,
    25,
    27,
    30,
    32,
    35,
    37,
    40,
    42,
    45,
    50,
    55,
    60,
    70,
    80,
)


def measure_contact_table(
    model: str = "prb3",
    frequencies: Floats = TABLE_FREQUENCIES,
    timesteps: Floats = (5e-5, 1e-4, 2e-4, 2.5e-4, 1e-3 / 3, 5e-4, 1e-3),
    integrators: Sequence[str] = ("implicitfast", "euler"),
    gap_m: float = 0.001,
    settle_s: float = 1.0,
    record_s: float = 1.0,
    timing_repeats: int = 3,
) -> pd.DataFrame:
    """Foot-path error (mm) of each timestep against ``REFERENCE_DT``, contacts per cycle, and the wall time
    per 10 s simulated (one thread, median of ``timing_repeats``), per frequency — the ``contact`` table.

    A timestep above half the contact time constant is measured but marked ``solref_clamped`` (never
    selected): MuJoCo's ``refsafe`` then raises the time constant to 2·dt, a softer contact than the rig's
    model (the foot path may still agree; the peak force does not)."""
    freqs = np.asarray(frequencies, float)
    timeconst = RigParams.with_overrides(beam_model(model).params.rig).contact_timeconst
    window = SimSettings(settle_s=settle_s, record_s=record_s)
    ref = contact_sweep(model, freqs, window.replace(timestep=REFERENCE_DT), gap_m=gap_m)
    ref_ratio = ref.contacts_per_cycle()
    runs = {}
    for integ in integrators:
        for h in timesteps:
            r = contact_sweep(model, freqs, window.replace(timestep=h, integrator=integ), gap_m=gap_m)
            err = np.sqrt(np.mean(np.sum((r.foot - ref.foot) ** 2, axis=2), axis=1)) * 1e3
            wall, cpu = time_contact(model, 25.0, h, seconds=2.0, repeats=timing_repeats, gap_m=gap_m, integrator=integ)
            runs[(integ, h)] = (r, err, r.contacts_per_cycle(), wall * 5.0, cpu * 5.0)
    # Where even the finest timesteps (≤ 1e-4 s) disagree with the reference — in the path by more than
    # IRREGULAR_MM or in the contact count — the regime is irregular (no timestep converges it pointwise).
    # There a timestep is judged by its excess over that floor and by a contact count inside the band the
    # fine runs span (± 0.1).
    fine = [k for k in runs if k[1] <= 1e-4]
    rows = []
    for i, f in enumerate(freqs):
        fine_err = max(runs[k][1][i] for k in fine) if fine else 0.0
        fine_ratio = [ref_ratio[i]] + [runs[k][2][i] for k in fine]
        lo, hi = np.nanmin(fine_ratio) - 0.1, np.nanmax(fine_ratio) + 0.1
        regular = fine_err <= IRREGULAR_MM and all(
            (math.isnan(q) and math.isnan(ref_ratio[i])) or abs(q - ref_ratio[i]) < 0.1 for q in fine_ratio
        )
        for (integ, h), (r, err, ratio, wall, cpu) in runs.items():
            q = ratio[i]
            if regular:
                same = (math.isnan(q) and math.isnan(ref_ratio[i])) or abs(q - ref_ratio[i]) < 0.1
                status, e = ("ok" if same else "wrong_contacts"), err[i]
            else:
                inside = (math.isnan(q) and math.isnan(ref_ratio[i])) or (lo <= q <= hi)
                status, e = ("irregular" if inside else "wrong_contacts"), max(0.0, err[i] - fine_err)
            if not r.ok[i]:
                status = "diverged"
            elif 2 * h > timeconst + 1e-12:
                status = "solref_clamped"
            rows.append(
                dict(
                    scene="contact",
                    model=model,
                    integrator=integ,
                    timestep=h,
                    frequency_hz=f,
                    status=status,
                    err_mm=e,
                    path_err_mm=err[i],
                    contacts_per_cycle=q,
                    ref_contacts_per_cycle=ref_ratio[i],
                    wall_s_per_10s=wall,
                    cpu_s_per_10s=cpu,
                    gap_m=gap_m,
                    is_reference=False,
                )
            )
    return pd.DataFrame(rows)


def bench_contact(out: Path, model: str = "prb3", tolerance_mm: float = 0.1, repeats: int = 3) -> dict:
    """The contact goals on a freshly measured table: 10 s at the default model, one run per frequency
    (1–45 Hz, one thread, median of ``repeats``), and the 45-frequency × 10 s sweep batched on all cores."""
    out = Path(out)
    table = measure_contact_table(model)
    table.to_csv(out / "contact_table.csv", index=False)
    return time_contact_goals(table, model, tolerance_mm, repeats) | {"table": str(out / "contact_table.csv")}


def time_contact_goals(table: pd.DataFrame, model: str = "prb3", tolerance_mm: float = 0.1, repeats: int = 3) -> dict:
    """Timing half of :func:`bench_contact` on a given table (e.g. the shipped one)."""
    from beambench.sim import selection as select

    freqs = np.arange(1, 46, dtype=float)
    plan = select.plan_sweep("contact", tolerance_mm, freqs, models=[model], table=table)
    dts = np.array([plan.timestep(f) for f in freqs])
    single = {}
    for f, h in zip(freqs, dts):
        w, c = time_contact(model, f, h, seconds=10.0, repeats=repeats, integrator=plan.integrator)
        single[f"{f:g}"] = {"timestep": float(h), "wall_s": w, "cpu_s": c}
    walls_1 = np.array([v["wall_s"] for v in single.values()])

    def sweep_wall(timesteps: float | tuple[float, ...]) -> list[float]:
        walls = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            sim = SimSettings(settle_s=0.0, record_s=10.0, integrator=plan.integrator, timestep=timesteps)
            r = contact_sweep(model, freqs, sim)
            walls.append(time.perf_counter() - t0)
            if not r.ok.all():
                raise RuntimeError(f"contact runs diverged at {freqs[~r.ok].tolist()} Hz")
        return walls

    walls = sweep_wall(tuple(float(h) for h in dts))
    fixed = sweep_wall(1e-4)
    return {
        "plan": plan.describe(),
        "single_run_10s": single,
        "single_run_10s_wall_s_median_over_freqs": float(np.median(walls_1)),
        "single_run_10s_wall_s_max_over_freqs": float(walls_1.max()),
        "single_run_10s_worst_freq_hz": float(freqs[int(np.argmax(walls_1))]),
        "sweep_45x10s_wall_s_median": float(np.median(walls)),
        "sweep_45x10s_wall_s_all": walls,
        "sweep_45x10s_fixed_dt_1e-4_wall_s_median": float(np.median(fixed)),
    }
