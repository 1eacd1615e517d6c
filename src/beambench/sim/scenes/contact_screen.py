"""A cheap screen of the contact twin's map: the landmarks a search needs from a few CPU-seconds per point.

The shipped protocol (1–40 Hz in 1 Hz steps, 2 s settle + 5 s record: 280 s of rig time, about a CPU-minute at
the converged timestep) is what a session records. A search over the physical box needs far less to tell one
point from another: :data:`SCREEN_FREQUENCIES` steps (2 Hz where the paper's landmarks are, 18–40 Hz; 4–6 Hz
below), stepped with the state carried over as ``beambench run`` does, each settled :data:`SCREEN_SETTLE_S` and
recorded :data:`SCREEN_RECORD_S`, noise off, at the point's converged timestep (:func:`converged_dt`). Per step it
reads what :func:`~beambench.sim.scenes.contact_regimes.stepped_regime_map` reads (the regime from the plate's
normal force, the tangential sign) plus the foot's **lift-off height**: the sole's highest point above the plate
in the record window (0 while it never leaves).

How well the screen agrees with the full protocol is measured, not assumed: ``benchmarks/bench_contact_search.py
--validate``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import pandas as pd

from beambench.acquisition.streams import CONTACT_MARKERS
from beambench.sim.scenes.contact_regimes import IRREGULAR, ContactTwin, regime_table
from beambench.sim.scenes.contact_rig import ContactRigSim, RigParams
from beambench.sim.scenes.step_regime import Classifier, StepWindow

SCREEN_FREQUENCIES = (4.0, 10.0, 14.0, 16.0, 18.0, 20.0, 22.0, 24.0, 26.0, 28.0, 30.0, 32.0, 34.0, 36.0, 38.0, 40.0)
SCREEN_SETTLE_S = 0.4  # s per step before the record window (the state carries from the step before)
SCREEN_RECORD_S = 0.6  # s per step recorded: 8 periods at 14 Hz, 5 contacts of a 1/3 at 26 Hz
MAX_DT = 5e-5  # s, the shipped twin's converged timestep (rig.max_timestep)
STEPS_PER_CONTACT_TIME = 20  # a contact of time constant tc·ζ is resolved in this many steps


def converged_dt(rig: RigParams) -> float:
    """The timestep a point's map runs at: the shipped twin's converged step, finer where the contact is stiffer
    (the contact's time scale tc·ζ resolved in :data:`STEPS_PER_CONTACT_TIME` steps)."""
    return min(MAX_DT, rig.contact_timeconst * rig.contact_dampratio / STEPS_PER_CONTACT_TIME)


def point_twin(values: Mapping[str, float], base: str = "physical") -> ContactTwin:
    """The rod5g contact twin of parameter set ``base`` with ``values`` applied: keys as the set's ``bounds:`` name
    them (SI): ``beam.<field>``, ``beam.material.<field>``, ``rig.<field>``; other keys (a search's option
    switches) are ignored. The contact's damping ratio moves at a fixed stiffness: MuJoCo's contact stiffness goes
    with 1/(tc·ζ)², so with ``rig.contact_dampratio`` given the time constant (the given one, else the set's) is
    scaled by 1/ζ and tc·ζ stays what it was."""
    from beambench.sim.models.params import load_params

    params = load_params(base, "rod")
    rig = {**params.rig}
    beam: dict[str, Any] = {}
    material: dict[str, float] = {}
    for key, v in values.items():
        block, _, name = key.partition(".")
        if block == "rig":
            rig[name] = v
        elif block == "beam" and name.startswith("material."):
            material[name.removeprefix("material.")] = v
        elif block == "beam":
            beam[name] = v
    if "rig.contact_dampratio" in values:
        tc = values.get("rig.contact_timeconst", params.rig.get("contact_timeconst", RigParams.contact_timeconst))
        rig["contact_timeconst"] = float(tc) / values["rig.contact_dampratio"]
    p = replace(params, material=replace(params.material, **material), **beam, rig=rig)
    return ContactTwin("rod5g", p, {})


def screen_map(
    twin: ContactTwin,
    frequencies: Sequence[float] = SCREEN_FREQUENCIES,
    settle_s: float = SCREEN_SETTLE_S,
    record_s: float = SCREEN_RECORD_S,
    twist_deg: float = 90.0,
    amplitude_m: float = 0.002,
    timestep: float | None = None,
) -> pd.DataFrame:
    """The stepped map of ``twin`` at ``frequencies`` (in that order), noise off: the columns of
    :data:`~beambench.sim.scenes.contact_regimes.REGIME_MAP_COLUMNS` plus ``liftoff_mm`` (the sole's highest
    point above the plate in the record window, mm; 0 if it never leaves). ``timestep`` None: :func:`converged_dt`."""
    bm, rig = twin.build()
    h = converged_dt(rig) if timestep is None else float(timestep)
    scene = ContactRigSim(bm, twist_deg, rig.plate_gap, amplitude_m, rig, "implicitfast", timestep=h)
    plate_top = -(rig.foot_length + rig.plate_gap)
    foot = CONTACT_MARKERS.index("foot")
    how = Classifier()
    rows, lift = [], []
    t_now = 0.0
    try:
        for f in frequencies:
            scene.set_frequency(float(f))
            scene.advance_to(t_now + settle_s)
            t_now += settle_s
            tr = scene.advance_to(t_now + record_s)
            keep = tr.t > t_now
            t_now += record_s
            nt = tr.channels["force_nt"][keep]
            xyz = tr.channels["markers"][keep, foot]
            row: dict = {"frequency_hz": float(f), "timestep": h, "ok": True}
            if keep.sum() < 2 or not np.isfinite(nt).all():
                rows.append(row | {"contacts_per_cycle": np.nan, "regime": IRREGULAR, "ok": False})
                lift.append(np.nan)
                continue
            t0 = float(tr.t[keep][0]) - h
            rows.append(row | how.classify(StepWindow(float(f), h, t0, nt[:, 0], nt[:, 1], xyz[:, 0])))
            lift.append(max(0.0, float(np.max(xyz[:, 2]) - plate_top)) * 1e3)
    finally:
        scene.physics.close()
    table = regime_table(rows, rig.plate_gap)
    table["liftoff_mm"] = lift
    return table
