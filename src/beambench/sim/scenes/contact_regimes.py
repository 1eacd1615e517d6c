"""The contact regime of each drive frequency, classified from the plate's normal force as ``beambench analyze``
does, and the landmarks of such a map.

- :func:`regime_map`: every frequency held from rest in one batched run (:mod:`beambench.sim.scenes.contact_sweep`);
- :func:`stepped_regime_map`: a stepped sweep through one scene, as the sim backend runs a protocol (the state
  carries from step to step);
- :func:`transitions`: a map's landmarks (continuous edge, lowest ½, lowest ⅓) — the one definition the
  calibration's targets, objective and reports use;
- :func:`static_sag`: how far the foot sinks under gravity (the sag the plate gap acts against).

Both maps classify each step's record window with the same classifier (:mod:`beambench.sim.scenes.step_regime`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np
import pandas as pd

from beambench.acquisition.forces.contact_events import ContactParams
from beambench.acquisition.streams import CONTACT_MARKERS
from beambench.common.types import Floats
from beambench.sim.models.beam import BeamModel
from beambench.sim.models.params import BeamParams, load_params
from beambench.sim.models.registry import make_beam_model, model_family
from beambench.sim.scene_params import RigParams
from beambench.sim.scenes.contact_rig import build_contact_spec
from beambench.sim.scenes.contact_sweep import contact_sweep
from beambench.sim.scenes.step_regime import Classifier, StepWindow
from beambench.sim.settings import SimSettings

CONTINUOUS, NONE, IRREGULAR = "continuous", "none", "irregular"  # regime labels beside "1", "1/2", "2" …

REGIME_MAP_COLUMNS = (
    "frequency_hz",
    "contacts_per_cycle",
    "regime",
    "tangential_sign",
    "touchdown_direction",
    "in_contact_fraction",
    "n_contacts",
    "mean_tangential_n",
    "peak_normal_n",
    "timestep",
    "ok",
)

REGIME_MAP_SIM = SimSettings(settle_s=1.5, record_s=2.0)  # regime_map's default window
STEPPED_MAP_SIM = SimSettings(settle_s=2.0, record_s=5.0, integrator="implicitfast")  # stepped_regime_map's


@dataclass(frozen=True)
class ContactTwin:
    """The contact scene a map runs: beam model family, parameter set (name, YAML path or
    :class:`BeamParams`; its ``rig:`` block sets the :class:`RigParams`) and ``rig_overrides`` on top (e.g.
    ``{"plate_gap": 0.0074}``, the gap h' from the unloaded foot)."""

    model: str = "prb3"
    params: str | BeamParams = "paper"
    rig_overrides: dict[str, Any] = field(default_factory=dict)

    def build(self) -> tuple[BeamModel, RigParams]:
        bp = load_params(self.params, model=model_family(self.model)) if isinstance(self.params, str) else self.params
        return make_beam_model(self.model, bp), RigParams.with_overrides({**bp.rig, **self.rig_overrides})


def regime_map(
    frequencies: Floats,
    sim: SimSettings = REGIME_MAP_SIM,
    twin: ContactTwin = ContactTwin(),
    contact: ContactParams | None = None,
) -> pd.DataFrame:
    """The contact regime at each drive frequency, fast: every frequency held from t = 0 in one batched run
    (:func:`~beambench.sim.scenes.contact_sweep.contact_sweep`), classified from the plate's normal force alone
    as ``beambench analyze`` does (:func:`beambench.acquisition.forces.contact_events.force_regime`).

    ``sim``: windows, twist, amplitude, timesteps (None: the measured table's), threads; the force is
    box-averaged over the load cells' sample period (1 ms) like the rig's load cells; ``sim.noise`` adds their
    noise (15 counts per raw channel through the shipped calibration) and 0.1 mm of mocap noise to the foot
    track (``sim.seed``).

    One row per frequency, columns :data:`REGIME_MAP_COLUMNS`:

    - ``contacts_per_cycle``: touchdowns per drive cycle (0 for continuous contact, NaN if diverged);
    - ``regime``: ``none``, ``continuous``, ``1``, ``1/2``, ``1/3``…, ``2``…, ``irregular``;
    - ``tangential_sign``: sign of the mean tangential force **of the foot on the plate** along +x (the
      stage's travel axis) while in contact — the load cells' tangential channel in a session
      (``steps.csv`` ``tangential_sign``); 0 without contact;
    - ``touchdown_direction``: sign of the median foot velocity along +x (relative to the plate) over the
      last 10 % of a period before each touchdown; 0 without touchdowns (e.g. continuous contact);
    - ``ok``: False where the run diverged (its regime is then ``irregular``).
    """
    freqs = np.asarray(frequencies, float)
    bm, rig = twin.build()
    sw = contact_sweep(bm, freqs, sim, gap_m=rig.plate_gap, rig=rig)
    how = Classifier.of(sim, contact)
    rows = []
    for i, f in enumerate(freqs):
        h = float(sw.timesteps[i])
        row: dict = {"frequency_hz": float(f), "timestep": h, "ok": bool(sw.ok[i])}
        normal, _z = sw.contact[i]
        tang, foot_x = sw.motion[i]
        if not sw.ok[i] or not np.isfinite(normal).all():
            rows.append(row | {"contacts_per_cycle": np.nan, "regime": IRREGULAR, "ok": False})
            continue
        rows.append(row | how.classify(StepWindow(float(f), h, sim.settle_s, normal, tang, foot_x)))
    df = regime_table(rows, rig.plate_gap)
    df.attrs["wall_s"] = sw.wall_s
    return df


def stepped_regime_map(
    frequencies: Floats,
    sim: SimSettings = STEPPED_MAP_SIM,
    twin: ContactTwin = ContactTwin(),
    contact: ContactParams | None = None,
    tolerance_mm: float = 0.1,
) -> pd.DataFrame:
    """The contact regime per step of a *stepped* sweep, as the sim backend runs a protocol: one
    :class:`ContactRigSim` (the run's scene: servo-driven stage, the motor's velocity ramp between steps, the
    timestep the measured table plans per frequency within ``tolerance_mm``, or a fixed ``sim.timestep``), the
    frequencies in the given order, each settled for ``sim.settle_s`` then recorded for ``sim.record_s``; the state carries over from
    step to step, so a regime that persists past its edge going up (hysteresis) shows here as in ``beambench
    run``, unlike :func:`regime_map` (every frequency from rest). Classified as :func:`regime_map` does; same
    columns. No device clocks or sample jitter: the load cells' 1 ms boxcar on the physics rows, ``sim.noise``
    for their noise."""
    from beambench.sim import selection as select
    from beambench.sim.scenes.contact_rig import ContactRigSim

    freqs = [float(f) for f in frequencies]
    bm, rig = twin.build()
    integrator = sim.integrator or "implicitfast"
    amp = sim.amplitude_m
    fixed = None if sim.timestep is None or isinstance(sim.timestep, tuple) else float(sim.timestep)
    plan = None
    if fixed is None:  # a protocol's fixed sim.timestep: the run plans nothing
        with contextlib.suppress(select.SelectionError):
            plan = select.plan_sweep("contact", tolerance_mm, freqs, models=[twin.model], integrators=[integrator])
    if plan is not None:
        scene = ContactRigSim(bm, sim.twist_deg, rig.plate_gap, amp, rig, plan.integrator, timestep_for=plan.timestep)
    else:
        scene = ContactRigSim(bm, sim.twist_deg, rig.plate_gap, amp, rig, integrator, timestep=fixed)
    how = Classifier.of(sim, contact)
    rows = []
    t_now = 0.0
    try:
        for f in freqs:
            scene.set_frequency(f)
            scene.advance_to(t_now + sim.settle_s)
            t_now += sim.settle_s
            tr = scene.advance_to(t_now + sim.record_s)
            keep = tr.t > t_now
            t_rec = tr.t[keep]
            t_now += sim.record_s
            normal = tr.channels["force_nt"][keep, 0]
            tang = tr.channels["force_nt"][keep, 1]
            foot_x = tr.channels["markers"][keep, CONTACT_MARKERS.index("foot"), 0]
            h = float(np.median(np.diff(t_rec))) if len(t_rec) > 1 else float(scene.physics.timestep)
            row: dict = {"frequency_hz": f, "timestep": h, "ok": True}
            if len(t_rec) < 2 or not np.isfinite(normal).all():
                rows.append(row | {"contacts_per_cycle": np.nan, "regime": IRREGULAR, "ok": False})
                continue
            rows.append(row | how.classify(StepWindow(f, h, float(t_rec[0]) - h, normal, tang, foot_x)))
    finally:
        scene.physics.close()
    return regime_table(rows, rig.plate_gap)


def regime_table(rows: list[dict], plate_gap_m: float) -> pd.DataFrame:
    """Regime rows → the map's table (both maps: the same columns, signs 0 where a step has none)."""
    df = pd.DataFrame(rows, columns=list(REGIME_MAP_COLUMNS))
    df["tangential_sign"] = df["tangential_sign"].fillna(0).astype(int)
    df["touchdown_direction"] = df["touchdown_direction"].fillna(0).astype(int)
    df.attrs["plate_gap_m"] = plate_gap_m
    return df


def transitions(frequencies: Floats, regimes: Sequence[str]) -> dict[str, float | None]:
    """A map's landmarks (Hz; any order of the steps), as a targets file names them:

    - ``continuous_below_hz``: the lowest frequency that is not continuous — the foot never leaves the plate
      below it. Counted only when the map starts continuous (else None); a map continuous throughout gives its
      top + 1 Hz;
    - ``half_at_hz`` / ``third_at_hz``: the lowest ``1/2`` / ``1/3`` step (None if the map has none)."""
    order = np.argsort(np.asarray(frequencies, float))
    f = np.asarray(frequencies, float)[order]
    lab = [str(regimes[i]) for i in order]
    edge = None
    if lab and lab[0] == CONTINUOUS:
        edge = next((float(x) for x, s in zip(f, lab) if s != CONTINUOUS), float(f[-1]) + 1.0)
    half = next((float(x) for x, s in zip(f, lab) if s == "1/2"), None)
    third = next((float(x) for x, s in zip(f, lab) if s == "1/3"), None)
    return {"continuous_below_hz": edge, "half_at_hz": half, "third_at_hz": third}


def static_sag(beam: BeamModel, rig: RigParams | None = None, twist_deg: float = 90.0) -> float:
    """How far (m) the sole sinks under gravity from its unloaded (natural) position with the plate out of
    reach — the sag against which the gap h' acts: sag > gap means the foot rests on the plate with a preload.
    2 s with the stage held, then the remaining swing damped out to the static equilibrium."""
    rig = rig or RigParams.with_overrides(beam.params.rig)
    spec = build_contact_spec(beam, twist_deg, 0.2, rig, "implicitfast", 2e-4)
    m = spec.compile()
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    site = m.site("foot").id
    z0 = float(d.site_xpos[site, 2])
    dof = m.jnt_dofadr[m.joint("stage").id]
    for _ in range(40):  # 2 s, stage held
        mujoco.mj_step(m, d, nstep=250)
        d.qpos[dof] = d.qvel[dof] = 0.0
    d.qvel[:] = 0.0
    for _ in range(20):
        mujoco.mj_step(m, d, nstep=100)
        d.qvel[:] *= 0.0
    mujoco.mj_forward(m, d)
    return z0 - float(d.site_xpos[site, 2])
