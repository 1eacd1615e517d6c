"""The contact-rig frequency sweep batched on all cores, with the timestep each frequency needs.

The scene is :func:`beambench.sim.scenes.contact_rig.build_contact_spec` (stage, beam, foot, plate); only the drive
differs from the interactive :class:`~beambench.sim.scenes.contact_rig.ContactRigSim`: each frequency is held from
t = 0 (no speed ramp) and the stage actuator is a pure feed-forward force M·a with the discrete acceleration
(as in :mod:`beambench.sim.scenes.free_beam`), so the clamp follows A·sin(2πft) exactly. Frequencies sharing a
timestep run in one :class:`mujoco.batch.Batch`.

:func:`measure_contact_table` writes the table :mod:`beambench.sim.selection` reads for ``scene="contact"``:
foot-path RMS error against the same model at a small timestep, contacts per cycle, wall time per 10 s.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pandas as pd

from beambench.acquisition.calibration import default_calibration
from beambench.acquisition.contact_events import ContactParams, force_contacts
from beambench.acquisition.streams import CONTACT_MARKERS, LOADCELL_RATE_HZ, MOCAP_RATE_HZ
from beambench.common.types import Floats
from beambench.sim.engine.batch import rollout_batch, thread_count, window
from beambench.sim.models.beam import BeamModel
from beambench.sim.models.params import BeamParams, load_params
from beambench.sim.models.registry import beam_model, make_beam_model, model_family
from beambench.sim.scenes.contact_rig import RigParams, build_contact_spec
from beambench.sim.scenes.free_beam import equilibrium_qpos, slider_inertia, stage_controls

REFERENCE_DT = 2.5e-5
IRREGULAR_MM = 0.05  # fine runs this far from the reference (foot path RMS) mark an irregular regime
SAMPLE_DT = 1e-3  # common sample grid of every timestep in the table (2.5e-5 … 1e-3 divide it)


@dataclass
class ContactSweep:
    """Per frequency: foot path [nf, n, 3] (m) and plate normal force [nf, n] (N) on the common sample grid
    ``t`` [n] (s); ``contact`` holds each run's normal force and foot height at every step of the window
    (for contact counting); ``ok`` False where a run diverged."""

    frequencies: np.ndarray
    timesteps: np.ndarray
    t: np.ndarray
    foot: np.ndarray
    normal: np.ndarray
    ok: np.ndarray
    wall_s: float
    contact: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)  # (normal, foot_z) per run
    # per run, every step of the window: tangential force of the foot on the plate along +x (N), foot x (m)
    motion: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    info: dict = field(default_factory=dict)

    def contacts_per_cycle(self) -> np.ndarray:
        """Flights per drive cycle at each frequency, from the full-resolution window (see contact_ratio)."""
        out = []
        for i, f in enumerate(self.frequencies):
            normal, z = self.contact[i]
            t = self.t[0] + np.arange(len(normal)) * self.timesteps[i]
            out.append(contact_ratio(t, normal, z, f) if self.ok[i] else float("nan"))
        return np.array(out)


def contact_ratio(t: np.ndarray, normal: np.ndarray, foot_z: np.ndarray, f: float) -> float:
    """Flights per drive cycle: a flight is a stretch with zero normal force longer than 10 % of a period in
    which the foot rises more than 20 µm above its lowest point (filters micro-chatter). With no flight the
    foot stays down (0) — or never touches (NaN)."""
    if not np.isfinite(normal).all():
        return float("nan")
    touching = normal > 1e-6
    if not touching.any():
        return float("nan")
    period = 1.0 / f
    dt = t[1] - t[0]
    low = np.nanmin(foot_z)
    flights = 0
    k = 0
    n = len(t)
    while k < n:
        if touching[k]:
            k += 1
            continue
        j = k
        while j < n and not touching[j]:
            j += 1
        if (j - k) * dt > 0.1 * period and foot_z[k:j].max() - low > 20e-6:
            flights += 1
        k = j
    cycles = (t[-1] - t[0] + dt) / period
    return flights / cycles


def _models(
    beam: BeamModel, twist_deg: float, gap_m: float, rig: RigParams, integrator: str, timesteps: Floats
) -> dict[float, mujoco.MjModel]:
    spec = build_contact_spec(beam, twist_deg, gap_m, rig, integrator, float(timesteps[0]))
    spec.delete(spec.sensor("clamp_force"))  # unused here; a force sensor costs a post-constraint RNE per step
    base = spec.compile()
    act = base.actuator("stage_servo").id
    base.actuator_gainprm[act, 0] = 1.0  # a pure force actuator: ctrl = M·a (feed-forward only)
    base.actuator_biasprm[act, :] = 0.0
    out = {}
    for h in sorted(set(float(x) for x in timesteps)):
        m = copy.copy(base)
        m.opt.timestep = h
        out[h] = m
    return out


def _rest(model: mujoco.MjModel, seconds: float = 0.5) -> np.ndarray:
    """Joint positions at rest (foot on or above the plate) with the stage held at x = 0 (1e-4 s implicitfast
    steps: the plate contact needs them)."""
    return equilibrium_qpos(model, seconds, mujoco.mjtIntegrator.mjINT_IMPLICITFAST, 1e-4)


def contact_sweep(
    beam: BeamModel | str = "prb3",
    frequencies: Floats = tuple(range(1, 46)),
    timesteps: Floats | float | None = None,
    twist_deg: float = 90.0,
    gap_m: float = 0.001,
    amplitude: float = 0.002,
    settle_s: float = 1.0,
    record_s: float = 1.0,
    integrator: str | None = None,
    sample_dt: float = SAMPLE_DT,
    rig: RigParams | None = None,
    nthread: int | None = None,
    timing: dict | None = None,
) -> ContactSweep:
    """Steady-state contact runs at each frequency, batched per timestep on all cores.

    ``timesteps``: one per frequency, one for all, or None for the timestep the measured contact table
    selects per frequency (``beambench.sim.selection``, tolerance 0.1 mm) — falling back to the rig's policy.
    ``integrator``: None for the table's choice with ``timesteps=None``, else implicitfast."""
    bm = beam_model(beam) if isinstance(beam, str) else beam
    freqs = np.asarray(frequencies, float)
    if timesteps is None:
        planned, planned_dts = default_contact_plan(bm.name, freqs)
        integrator = integrator or planned
        dts = planned_dts
    else:
        dts = np.broadcast_to(np.asarray(timesteps, float), freqs.shape).copy()
    integrator = integrator or "implicitfast"
    rig = rig or RigParams.with_overrides(bm.params.rig)
    models = _models(bm, twist_deg, gap_m, rig, integrator, dts)
    q0 = _rest(next(iter(models.values())))
    nt = round(float(record_s / sample_dt))
    foot = np.full((len(freqs), nt, 3), np.nan)
    normal = np.full((len(freqs), nt), np.nan)
    ok = np.ones(len(freqs), bool)
    contact: list = [None] * len(freqs)
    motion: list = [None] * len(freqs)
    walls: list[float] = []

    def run_group(h: float, idx: np.ndarray, threads: int | None) -> None:
        """Runs ``idx`` (all at timestep h) in one batch; fills their rows of the outputs."""
        m = models[h]
        every = max(1, round(float(sample_dt / h)))
        n_total, keep = window(settle_s, record_s, h, every)
        keep = keep[:nt]
        mass = slider_inertia(m, q0)
        dof = m.jnt_dofadr[m.joint("stage").id]
        qvel0 = np.zeros((len(idx), m.nv))
        for j, i in enumerate(idx):
            qvel0[j, dof] = stage_controls(freqs[i], amplitude, h, 1, mass, integrator)[1]

        def controls(k0: int, n: int) -> np.ndarray:
            c = np.empty((len(idx), n, 1))
            for j, i in enumerate(idx):
                c[j, :, 0] = stage_controls(freqs[i], amplitude, h, n, mass, integrator, k0)[0]
            return c

        a_foot = int(m.sensor("foot").adr[0])
        a_plate = int(m.sensor("plate_force").adr[0])
        n_settle = int(keep[0])
        full_n = np.zeros((len(idx), n_total - n_settle), np.float32)
        full_z = np.zeros((len(idx), n_total - n_settle), np.float32)
        full_t = np.zeros((len(idx), n_total - n_settle), np.float32)
        full_x = np.zeros((len(idx), n_total - n_settle), np.float32)

        def grab(k0: int, rows: np.ndarray) -> None:
            a = max(k0, n_settle)
            b = k0 + rows.shape[1]
            if b > a:
                full_n[:, a - n_settle : b - n_settle] = -rows[:, a - k0 : b - k0, a_plate + 3]
                full_z[:, a - n_settle : b - n_settle] = rows[:, a - k0 : b - k0, a_foot + 2]
                full_t[:, a - n_settle : b - n_settle] = rows[:, a - k0 : b - k0, a_plate + 1]
                full_x[:, a - n_settle : b - n_settle] = rows[:, a - k0 : b - k0, a_foot]

        sd, okg, w = rollout_batch(
            [m] * len(idx),
            np.tile(q0, (len(idx), 1)),
            qvel0,
            controls,
            n_total,
            keep,
            threads,
            on_chunk=grab,
            timing=timing,
        )
        for j, i in enumerate(idx):
            contact[i] = (full_n[j], full_z[j])
            motion[i] = (full_t[j], full_x[j])
        walls.append(w)
        foot[idx, : len(keep)] = sd[:, :, a_foot : a_foot + 3]
        normal[idx, : len(keep)] = -sd[:, :, a_plate + 3]  # contact sensor: force of the foot on the plate
        ok[idx] = okg & np.isfinite(sd[:, :, a_foot]).all(axis=1)

    for h in models:
        every = max(1, round(float(sample_dt / h)))
        if abs(every * h - sample_dt) > 1e-12:
            raise ValueError(f"timestep {h:g} does not divide the sample interval {sample_dt:g}")
    workers = thread_count(nthread, len(freqs))
    if workers == 1 or timing is not None:
        for h in models:
            run_group(h, np.nonzero(dts == h)[0], nthread)
        wall = float(sum(walls))
    else:  # balanced: each worker thread steps its share of the runs, one MuJoCo thread each
        t0 = time.perf_counter()

        def run_share(share: list[tuple[float, np.ndarray]]) -> None:
            for h, idx in share:
                run_group(h, idx, 1)

        with ThreadPoolExecutor(workers) as pool:
            jobs = [pool.submit(run_share, share) for share in _balanced_shares(dts, settle_s + record_s, workers)]
            for job in jobs:
                job.result()
        wall = time.perf_counter() - t0
    t = settle_s + np.arange(nt) * sample_dt
    return ContactSweep(
        freqs,
        dts,
        t,
        foot,
        normal,
        ok,
        wall,
        contact,
        motion,
        {"model": bm.name, "gap_m": gap_m, "integrator": integrator, "twist_deg": twist_deg},
    )


def _balanced_shares(dts: np.ndarray, seconds: float, workers: int) -> list[list[tuple[float, np.ndarray]]]:
    """Split the runs over ``workers`` so each steps about the same number of steps (longest first onto the
    least loaded), as (timestep, run indices) groups per worker."""
    load = [0.0] * workers
    picks: list[dict[float, list[int]]] = [{} for _ in range(workers)]
    for i in sorted(range(len(dts)), key=lambda i: dts[i]):  # smallest step = most steps first
        w = int(np.argmin(load))
        load[w] += seconds / dts[i]
        picks[w].setdefault(float(dts[i]), []).append(i)
    return [[(h, np.array(ix)) for h, ix in p.items()] for p in picks if p]


def static_sag(beam: BeamModel, rig: RigParams | None = None, twist_deg: float = 90.0) -> float:
    """How far (m) the sole sinks under gravity from its unloaded (natural) position with no plate — the sag
    against which the gap h' acts: sag > gap means the foot rests on the plate with a preload."""
    rig = rig or RigParams.with_overrides(beam.params.rig)
    m = next(iter(_models(beam, twist_deg, 1.0, rig, "implicitfast", [1e-4]).values()))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    z0 = float(d.site("foot").xpos[2])
    d.qpos[:] = _rest(m, 1.5)
    mujoco.mj_forward(m, d)
    return z0 - float(d.site("foot").xpos[2])


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
LOADCELL_NOISE_COUNTS = 15.0  # per raw channel, as the sim backend's load cells (sim.noise: true)
MOCAP_NOISE_M = 1e-4  # per axis, as the sim backend's mocap


def regime_map(
    frequencies: Floats,
    *,
    model: str = "prb3",
    params: str | BeamParams = "paper",
    rig_overrides: dict | None = None,
    settle_s: float = 1.5,
    record_s: float = 2.0,
    nthread: int | None = None,
    noise: bool = False,
    seed: int = 0,
    timesteps: Floats | float | None = None,
    twist_deg: float = 90.0,
    amplitude: float = 0.002,
    contact: ContactParams | None = None,
) -> pd.DataFrame:
    """The contact regime at each drive frequency, fast: every frequency held from t = 0 in one batched run
    (:func:`contact_sweep`), classified from the plate's normal force alone as ``beambench analyze`` does
    (:func:`beambench.acquisition.contact_events.force_regime`).

    ``params``: a parameter-set name (``sim_backend/<family>_<name>.yaml``), a YAML path or a
    :class:`BeamParams`; its ``rig:`` block, then ``rig_overrides`` (e.g. ``{"plate_gap": 0.0074}``) set the
    :class:`RigParams`, including the gap h' from the unloaded foot. The force is box-averaged over the load
    cells' sample period (1 ms) like the rig's load cells; ``noise`` adds their noise (15 counts per raw
    channel through the shipped calibration) and 0.1 mm of mocap noise to the foot track (``seed``).

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
    bp = load_params(params, model=model_family(model)) if isinstance(params, str) else params
    bm = make_beam_model(model, bp)
    rig = RigParams.with_overrides({**bp.rig, **(rig_overrides or {})})
    sw = contact_sweep(
        bm,
        freqs,
        timesteps,
        twist_deg=twist_deg,
        gap_m=rig.plate_gap,
        amplitude=amplitude,
        settle_s=settle_s,
        record_s=record_s,
        rig=rig,
        nthread=nthread,
    )
    cp = contact or ContactParams()
    rng = np.random.default_rng(seed)
    cal = default_calibration()
    rows = []
    for i, f in enumerate(freqs):
        h = float(sw.timesteps[i])
        row: dict = {"frequency_hz": float(f), "timestep": h, "ok": bool(sw.ok[i])}
        normal, _z = sw.contact[i]
        tang, foot_x = sw.motion[i]
        if not sw.ok[i] or not np.isfinite(normal).all():
            rows.append(row | {"contacts_per_cycle": np.nan, "regime": "irregular", "ok": False})
            continue
        rows.append(row | _classify(float(f), h, settle_s, normal, tang, foot_x, noise, rng, cal, cp))
    df = _regime_table(rows, rig.plate_gap)
    df.attrs["wall_s"] = sw.wall_s
    return df


def _regime_table(rows: list[dict], plate_gap_m: float) -> pd.DataFrame:
    """Regime rows → the map's table (both maps: the same columns, signs 0 where a step has none)."""
    df = pd.DataFrame(rows, columns=list(REGIME_MAP_COLUMNS))
    df["tangential_sign"] = df["tangential_sign"].fillna(0).astype(int)
    df["touchdown_direction"] = df["touchdown_direction"].fillna(0).astype(int)
    df.attrs["plate_gap_m"] = plate_gap_m
    return df


def _classify(
    f: float,
    h: float,
    t0: float,
    normal: np.ndarray,
    tang: np.ndarray,
    foot_x: np.ndarray,
    noise: bool,
    rng: np.random.Generator,
    cal: Any,
    cp: ContactParams,
) -> dict:
    """One step's regime row from its record window (rows every ``h`` s from ``t0``): the plate's normal and
    tangential force box-averaged over the load cells' sample period (optional load-cell noise), classified by
    :func:`force_contacts`; the foot's x track as the mocap sees it for the touchdown direction."""
    box = 1.0 / LOADCELL_RATE_HZ
    every = max(1, round(box / h))
    nb = len(normal) // every
    force = np.column_stack(
        [
            normal[: nb * every].reshape(nb, every).mean(axis=1),
            tang[: nb * every].reshape(nb, every).mean(axis=1),
        ]
    )
    if noise:
        counts = cal.counts_from_force(force)
        counts = np.round(counts + rng.normal(0.0, LOADCELL_NOISE_COUNTS, counts.shape))
        force = cal.force_from_counts(counts)
    t = t0 + (np.arange(nb) + 1) * box  # each sample at the end of its averaging interval
    c, summ = force_contacts(t, force[:, 0], float(f), cp)
    ft_in = force[c.mask, 1]
    mean_ft = float(np.mean(ft_in)) if len(ft_in) else np.nan
    # foot track as the mocap sees it (360 Hz, optional noise), velocity by central differences
    step = max(1, round(1.0 / (MOCAP_RATE_HZ * h)))
    xm = foot_x[::step].astype(float)
    tm = t0 + np.arange(len(xm)) * step * h
    if noise:
        xm = xm + rng.normal(0.0, MOCAP_NOISE_M, xm.shape)
    v = np.gradient(xm, tm) if len(xm) > 1 else np.zeros_like(xm)
    win = 0.1 / f
    td_v = [
        float(np.mean(v[(tm >= td - win) & (tm <= td)]))
        for td in c.touchdown_s
        if np.any((tm >= td - win) & (tm <= td))
    ]
    med = float(np.median(td_v)) if td_v else np.nan
    return {
        "contacts_per_cycle": summ.contacts_per_cycle,
        "regime": summ.regime,
        "tangential_sign": _sign(mean_ft),
        "touchdown_direction": _sign(med),
        "in_contact_fraction": summ.in_contact_fraction,
        "n_contacts": summ.n_contacts,
        "mean_tangential_n": mean_ft,
        "peak_normal_n": float(force[:, 0].max()) if len(force) else np.nan,
    }


def stepped_regime_map(
    frequencies: Floats,
    *,
    model: str = "prb3",
    params: str | BeamParams = "paper",
    rig_overrides: dict | None = None,
    settle_s: float = 2.0,
    record_s: float = 5.0,
    noise: bool = False,
    seed: int = 0,
    twist_deg: float = 90.0,
    amplitude: float = 0.002,
    integrator: str = "implicitfast",
    tolerance_mm: float = 0.1,
    contact: ContactParams | None = None,
) -> pd.DataFrame:
    """The contact regime per step of a *stepped* sweep, as the sim backend runs a protocol: one
    :class:`ContactRigSim` (the run's scene: servo-driven stage, the motor's velocity ramp between steps, the
    timestep the measured table plans per frequency), the frequencies in the given order, each settled for
    ``settle_s`` then recorded for ``record_s``; the state carries over from step to step, so a regime that
    persists past its edge going up (hysteresis) shows here as in ``beambench run``, unlike :func:`regime_map`
    (every frequency from rest). Classified as :func:`regime_map` does; same columns. No device clocks or
    sample jitter: the load cells' 1 ms boxcar on the physics rows, ``noise`` for their noise."""
    from beambench.sim import selection as select
    from beambench.sim.scenes.contact_rig import ContactRigSim

    freqs = [float(f) for f in frequencies]
    bp = load_params(params, model=model_family(model)) if isinstance(params, str) else params
    bm = make_beam_model(model, bp)
    rig = RigParams.with_overrides({**bp.rig, **(rig_overrides or {})})
    try:
        plan = select.plan_sweep("contact", tolerance_mm, freqs, models=[model], integrators=[integrator])
        scene = ContactRigSim(bm, twist_deg, rig.plate_gap, amplitude, rig, plan.integrator, timestep_for=plan.timestep)
    except select.SelectionError:
        scene = ContactRigSim(bm, twist_deg, rig.plate_gap, amplitude, rig, integrator)
    cp = contact or ContactParams()
    rng = np.random.default_rng(seed)
    cal = default_calibration()
    rows = []
    t_now = 0.0
    try:
        for f in freqs:
            scene.set_frequency(f)
            scene.advance_to(t_now + settle_s)
            t_now += settle_s
            tr = scene.advance_to(t_now + record_s)
            keep = tr.t > t_now
            t_rec = tr.t[keep]
            t_now += record_s
            normal = tr.channels["force_nt"][keep, 0]
            tang = tr.channels["force_nt"][keep, 1]
            foot_x = tr.channels["markers"][keep, CONTACT_MARKERS.index("foot"), 0]
            h = float(np.median(np.diff(t_rec))) if len(t_rec) > 1 else float(scene.physics.timestep)
            row: dict = {"frequency_hz": f, "timestep": h, "ok": True}
            if len(t_rec) < 2 or not np.isfinite(normal).all():
                rows.append(row | {"contacts_per_cycle": np.nan, "regime": "irregular", "ok": False})
                continue
            rows.append(row | _classify(f, h, float(t_rec[0]) - h, normal, tang, foot_x, noise, rng, cal, cp))
    finally:
        scene.physics.close()
    return _regime_table(rows, rig.plate_gap)


def _sign(x: float) -> int:
    return 0 if not np.isfinite(x) or x == 0 else int(np.sign(x))


def transitions(frequencies: Floats, regimes: Sequence[str]) -> dict[str, float]:
    """The map's landmarks: ``continuous_below_hz`` (the highest frequency up to which every step is
    continuous, 0 if the first is not), ``half_at_hz`` / ``third_at_hz`` (the lowest ``1/2`` / ``1/3``, NaN if
    none). Frequencies in ascending order."""
    order = np.argsort(np.asarray(frequencies, float))
    f = np.asarray(frequencies, float)[order]
    lab = [str(regimes[i]) for i in order]
    cont = 0.0
    for fi, li in zip(f, lab):
        if li != "continuous":
            break
        cont = float(fi)

    def lowest(name: str) -> float:
        hits = [float(fi) for fi, li in zip(f, lab) if li == name]
        return min(hits) if hits else float("nan")

    return {"continuous_below_hz": cont, "half_at_hz": lowest("1/2"), "third_at_hz": lowest("1/3")}


def default_contact_plan(model: str, frequencies: Floats, tolerance_mm: float = 0.1) -> tuple[str, np.ndarray]:
    """(integrator, timestep per frequency) the measured contact table picks for ``model``, else implicitfast
    with the rig's default timestep policy."""
    from beambench.sim import selection as select
    from beambench.sim.scenes.contact_rig import default_timestep

    try:
        plan = select.plan_sweep("contact", tolerance_mm, frequencies, models=[model])
        return plan.integrator, np.array([plan.timestep(f) for f in frequencies])
    except select.SelectionError:
        return "implicitfast", np.array([default_timestep(f) for f in frequencies])


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
    for _ in range(repeats):
        timing: dict = {}
        contact_sweep(
            beam,
            [frequency],
            [timestep],
            gap_m=gap_m,
            settle_s=0.0,
            record_s=seconds,
            integrator=integrator,
            nthread=1,
            timing=timing,
        )
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
    ref = contact_sweep(model, freqs, REFERENCE_DT, gap_m=gap_m, settle_s=settle_s, record_s=record_s)
    ref_ratio = ref.contacts_per_cycle()
    runs = {}
    for integ in integrators:
        for h in timesteps:
            r = contact_sweep(model, freqs, h, gap_m=gap_m, settle_s=settle_s, record_s=record_s, integrator=integ)
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

    def sweep_wall(timesteps) -> list[float]:
        walls = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            r = contact_sweep(model, freqs, timesteps, settle_s=0.0, record_s=10.0, integrator=plan.integrator)
            walls.append(time.perf_counter() - t0)
            if not r.ok.all():
                raise RuntimeError(f"contact runs diverged at {freqs[~r.ok].tolist()} Hz")
        return walls

    walls = sweep_wall(dts)
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
