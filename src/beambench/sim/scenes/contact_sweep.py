"""The contact-rig frequency sweep batched on all cores, with the timestep each frequency needs.

The scene is :func:`beambench.sim.scenes.contact_rig.build_contact_spec` (stage, beam, foot, plate); only the drive
differs from the interactive :class:`~beambench.sim.scenes.contact_rig.ContactRigSim`: each frequency is held from
t = 0 (no speed ramp) and the stage actuator is a pure feed-forward force M·a with the discrete acceleration
(as in :mod:`beambench.sim.scenes.free_beam`), so the clamp follows A·sin(2πft) exactly. Frequencies sharing a
timestep run in one :class:`mujoco.batch.Batch`.

The regime classification of these runs is :mod:`beambench.sim.scenes.contact_regimes`; the measurement of the
timestep table :mod:`beambench.sim.selection` reads for ``scene="contact"`` is
:mod:`beambench.studies.contact_table`.
"""

from __future__ import annotations

import copy
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import mujoco
import numpy as np

from beambench.acquisition.protocol.scenes import CONTACT
from beambench.common.types import Floats
from beambench.sim.engine.batch import rollout_batch, thread_count, window
from beambench.sim.models.beam import BeamModel
from beambench.sim.models.registry import beam_model
from beambench.sim.scene_params import RigParams
from beambench.sim.scenes.contact_rig import build_contact_spec
from beambench.sim.scenes.free_beam import equilibrium_qpos, slider_inertia, stage_controls
from beambench.sim.scenes.registry import BatchJob, BatchTask, ContactTrace, JobRun, batched
from beambench.sim.settings import SimSettings

SWEEP_SIM = SimSettings()  # contact_sweep's default: 1 s settle, 1 s record, 90°, 2 mm, the table's timesteps
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
    sim: SimSettings = SWEEP_SIM,
    *,
    gap_m: float = 0.001,
    rig: RigParams | None = None,
    sample_dt: float = SAMPLE_DT,
    timing: dict | None = None,
) -> ContactSweep:
    """Steady-state contact runs at each frequency, batched per timestep on all cores (``sim.nthread``).

    ``sim``: the windows, twist and amplitude; ``sim.timestep`` one per frequency, one for all, or None for the
    timestep the measured contact table selects per frequency (``beambench.sim.selection``, tolerance 0.1 mm) —
    falling back to the rig's policy; ``sim.integrator`` None for the table's choice with ``timestep=None``, else
    implicitfast. ``timing``: filled with one run's wall and CPU time (runs the groups one after the other)."""
    bm = beam_model(beam) if isinstance(beam, str) else beam
    freqs = np.asarray(frequencies, float)
    integrator = sim.integrator
    rig = rig or RigParams.with_overrides(bm.params.rig)
    if sim.timestep is None:
        planned, dts = default_contact_plan(bm.name, freqs, max_timestep=rig.max_timestep)
        integrator = integrator or planned
    else:
        dts = np.broadcast_to(np.asarray(sim.timestep, float), freqs.shape).copy()
    integrator = integrator or "implicitfast"
    run = _SweepRun(_models(bm, sim.twist_deg, gap_m, rig, integrator, dts), freqs, sim, integrator, sample_dt, timing)
    workers = thread_count(sim.nthread, len(freqs))
    if workers == 1 or timing is not None:
        for h in run.models:
            run.group(h, np.nonzero(dts == h)[0], sim.nthread)
        wall = float(sum(run.walls))
    else:  # balanced: each worker thread steps its share of the runs, one MuJoCo thread each
        t0 = time.perf_counter()

        def run_share(share: list[tuple[float, np.ndarray]]) -> None:
            for h, idx in share:
                run.group(h, idx, 1)

        with ThreadPoolExecutor(workers) as pool:
            shares = _balanced_shares(dts, sim.settle_s + sim.record_s, workers)
            for job in [pool.submit(run_share, share) for share in shares]:
                job.result()
        wall = time.perf_counter() - t0
    t = sim.settle_s + np.arange(run.nt) * sample_dt
    info = {"model": bm.name, "gap_m": gap_m, "integrator": integrator, "twist_deg": sim.twist_deg}
    return ContactSweep(freqs, dts, t, run.foot, run.normal, run.ok, wall, run.contact, run.motion, info)


@batched(CONTACT)
def run_sweep_task(task: BatchTask) -> list[JobRun]:
    """A sweep's jobs, one :func:`contact_sweep` per point (its frequencies together) in this thread: the foot and
    the stage on the ``task.sample_dt`` grid, the plate's normal force and the foot height at every step."""
    groups: dict[str, list[BatchJob]] = {}
    for job in task.jobs:
        groups.setdefault(job.group, []).append(job)
    runs: list[JobRun] = []
    for jobs in groups.values():
        first = jobs[0]
        sim = SimSettings(
            settle_s=task.settle_s,
            record_s=task.record_s,
            twist_deg=first.twist_deg,
            amplitude_m=first.amplitude_m,
            integrator=first.integrator,
            timestep=first.timestep,
            nthread=1,
        )
        freqs = [j.frequency_hz for j in jobs]
        r = contact_sweep(first.beam, freqs, sim, gap_m=first.point["gap_mm"] * 1e-3, sample_dt=task.sample_dt)
        t = r.t
        for i, job in enumerate(jobs):
            h = float(r.timesteps[i])
            if not r.ok[i]:
                runs.append(JobRun(job.index, False, t, reason=f"{job.integrator}: MuJoCo stopped", timestep_s=h))
                continue
            normal, foot_z = r.contact[i]
            trace = ContactTrace(
                t[0] + np.arange(len(normal)) * h, np.asarray(normal, float), np.asarray(foot_z, float)
            )
            stage = job.amplitude_m * np.sin(2 * np.pi * job.frequency_hz * t)
            runs.append(JobRun(job.index, True, t, stage=stage, foot=r.foot[i], contact=trace, timestep_s=h))
    return sorted(runs, key=lambda r: r.index)


class _SweepRun:
    """The outputs of one :func:`contact_sweep`, filled one timestep group at a time (from worker threads)."""

    def __init__(
        self,
        models: dict[float, mujoco.MjModel],
        freqs: np.ndarray,
        sim: SimSettings,
        integrator: str,
        sample_dt: float,
        timing: dict | None,
    ) -> None:
        for h in models:
            every = max(1, round(float(sample_dt / h)))
            if abs(every * h - sample_dt) > 1e-12:
                raise ValueError(f"timestep {h:g} does not divide the sample interval {sample_dt:g}")
        self.models, self.freqs, self.sim, self.integrator = models, freqs, sim, integrator
        self.sample_dt, self.timing = sample_dt, timing
        self.q0 = _rest(next(iter(models.values())))
        self.nt = round(float(sim.record_s / sample_dt))
        n = len(freqs)
        self.foot = np.full((n, self.nt, 3), np.nan)
        self.normal = np.full((n, self.nt), np.nan)
        self.ok = np.ones(n, bool)
        self.contact: list = [None] * n
        self.motion: list = [None] * n
        self.walls: list[float] = []

    def group(self, h: float, idx: np.ndarray, threads: int | None) -> None:
        """Runs ``idx`` (all at timestep h) in one batch; fills their rows of the outputs."""
        m, freqs, amplitude, integrator = self.models[h], self.freqs, self.sim.amplitude_m, self.integrator
        every = max(1, round(float(self.sample_dt / h)))
        n_total, keep = window(self.sim.settle_s, self.sim.record_s, h, every)
        keep = keep[: self.nt]
        mass = slider_inertia(m, self.q0)
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
        full = np.zeros((4, len(idx), n_total - n_settle), np.float32)  # normal, foot z, tangential, foot x

        def grab(k0: int, rows: np.ndarray) -> None:
            a = max(k0, n_settle)
            b = k0 + rows.shape[1]
            if b > a:
                cols = (a_plate + 3, a_foot + 2, a_plate + 1, a_foot)
                for c, (col, sign) in enumerate(zip(cols, (-1.0, 1.0, 1.0, 1.0))):
                    full[c, :, a - n_settle : b - n_settle] = sign * rows[:, a - k0 : b - k0, col]

        sd, okg, w = rollout_batch(
            [m] * len(idx),
            np.tile(self.q0, (len(idx), 1)),
            qvel0,
            controls,
            n_total,
            keep,
            threads,
            on_chunk=grab,
            timing=self.timing,
        )
        for j, i in enumerate(idx):
            self.contact[i] = (full[0, j], full[1, j])
            self.motion[i] = (full[2, j], full[3, j])
        self.walls.append(w)
        self.foot[idx, : len(keep)] = sd[:, :, a_foot : a_foot + 3]
        self.normal[idx, : len(keep)] = -sd[:, :, a_plate + 3]  # contact sensor: force of the foot on the plate
        self.ok[idx] = okg & np.isfinite(sd[:, :, a_foot]).all(axis=1)


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


def default_contact_plan(
    model: str, frequencies: Floats, tolerance_mm: float = 0.1, max_timestep: float = 0.0
) -> tuple[str, np.ndarray]:
    """(integrator, timestep per frequency) the measured contact table picks for ``model``, else implicitfast
    with the rig's default timestep policy, capped at ``max_timestep`` (> 0: the twin's converged timestep)."""
    from beambench.sim import selection as select
    from beambench.sim.scenes.contact_rig import capped, default_timestep

    try:
        plan = select.plan_sweep("contact", tolerance_mm, frequencies, models=[model])
        return plan.integrator, np.array([capped(plan.timestep(f), max_timestep) for f in frequencies])
    except select.SelectionError:
        return "implicitfast", np.array([default_timestep(f, max_timestep) for f in frequencies])
