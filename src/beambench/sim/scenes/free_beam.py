"""The free-beam scene (paper Fig. 2c–g): a stage shakes the clamp along x with x = A·sin(2πft); no contact.

Same frame as the contact rig: x = stage travel, y = along the beam, z = up, gravity −z (optional). The stage
is a slider with a large armature driven by a pure feed-forward force M·a, where a is the *discrete*
acceleration the integrator realises, so the clamp follows the sine to floating-point accuracy whatever the
beam does (for RK4, whose control is held over the four stages, a matching exact-position recursion).

Runs are batched over frequencies (or over twist angles) with :class:`mujoco.batch.Batch` on all cores.
Trajectories come from sensors only: a sensor row recorded after substep k was evaluated *before* it, at
time k·h — the state rows are one step later and are never mixed in.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np

from beambench.acquisition.protocol.scenes import FREE_BEAM
from beambench.common.types import Floats
from beambench.sim.engine.batch import rollout_batch, window
from beambench.sim.engine.stability import unstable_reason
from beambench.sim.engine.stepping import integrator_enum
from beambench.sim.models.beam import BeamModel, add_beam
from beambench.sim.models.registry import beam_model
from beambench.sim.scenes.registry import BatchTask, JobRun, batched
from beambench.sim.settings import SimSettings

DEFAULT_INTEGRATOR = "implicitfast"
DEFAULT_TIMESTEP = 1e-4  # s

STAGE_ARMATURE = 1000.0  # kg
TIP_DIVERGED_M = 0.5  # a tip this far from the clamp means the run blew up


def build_free_beam_spec(
    beam: BeamModel,
    twist_deg: float = 90.0,
    integrator: str = "implicitfast",
    timestep: float = 1e-4,
    gravity: bool = True,
) -> mujoco.MjSpec:
    """World → stage (slide x, armature) → clamp → beam; sensors ``tip`` (framepos), ``stage`` (jointpos)."""
    integrator_id = integrator_enum(integrator)
    spec = mujoco.MjSpec()
    spec.modelname = "beambench_free_beam"
    spec.option.timestep = timestep
    spec.option.integrator = integrator_id
    spec.option.gravity = [0, 0, -9.81 if gravity else 0.0]
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    spec.compiler.fusestatic = True  # the clamp and tip bodies carry no joints: fold them into their parents
    stage = spec.worldbody.add_body(name="stage")
    stage.add_joint(name="stage", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0], armature=STAGE_ARMATURE)
    stage.add_geom(
        type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.02, 0.01, 0.01], pos=[0, -0.01, 0], mass=0.15, contype=0, conaffinity=0
    )
    clamp = stage.add_body(name="clamp")
    sites = add_beam(clamp, beam, twist_deg)
    spec.add_actuator(name="stage_force", target="stage", trntype=mujoco.mjtTrn.mjTRN_JOINT)
    spec.add_sensor(
        name="tip", type=mujoco.mjtSensor.mjSENS_FRAMEPOS, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=sites.tip_site
    )
    spec.add_sensor(
        name="stage", type=mujoco.mjtSensor.mjSENS_JOINTPOS, objtype=mujoco.mjtObj.mjOBJ_JOINT, objname="stage"
    )
    return spec


def equilibrium_qpos(
    model: mujoco.MjModel,
    seconds: float = 3.0,
    integrator: mujoco.mjtIntegrator = mujoco.mjtIntegrator.mjINT_DISCRETE,
    timestep: float = 1e-3,
) -> np.ndarray:
    """Joint positions at rest under gravity with the stage held at x = 0. The default ``discrete`` integrator
    is implicit in the springs, so any dt is stable; a scene with contact passes a small implicitfast step."""
    m = copy.copy(model)
    m.opt.integrator = integrator
    m.opt.timestep = timestep
    d = mujoco.MjData(m)
    stage = m.jnt_dofadr[m.joint("stage").id]
    for _ in range(int(seconds / timestep) // 100):
        mujoco.mj_step(m, d, nstep=100)
        d.qpos[stage] = d.qvel[stage] = 0.0
    return d.qpos.copy()


def stage_controls(
    freq: float, amplitude: float, h: float, n: int, mass: float, integrator: str, k0: int = 0
) -> tuple[np.ndarray, float]:
    """Forces for steps k0..k0+n−1 that make the slider realise x_k = A·sin(2πf·k·h) exactly; and v_{k0}."""
    w = 2 * math.pi * freq
    k = np.arange(k0 - 1, k0 + n + 1)
    x = amplitude * np.sin(w * h * k)  # x_{k0-1} .. x_{k0+n}
    if integrator != "rk4":
        acc = (x[2:] - 2 * x[1:-1] + x[:-2]) / h**2  # semi-implicit: v+ = v + h a, x+ = x + h v+
        v0 = (x[1] - x[0]) / h
        return mass * acc, v0
    # RK4 with the force held over the step: x+ = x + h v + h²a/2, v+ = v + h a. Exact positions, and the
    # velocity recursion v+ = −v + 2Δx/h keeps its O(h²) error bounded (it alternates in sign).
    v0 = amplitude * w * math.cos(w * h * k0)
    dx = 2 * np.diff(x[1:]) / h  # 2Δx_k/h for k = k0..k0+n-1
    sign = (-1.0) ** np.arange(n + 1)
    v = sign * (v0 + np.concatenate([[0.0], np.cumsum(sign[1:] * dx)]))
    acc = 2 * (np.diff(x[1:]) - h * v[:-1]) / h**2
    return mass * acc, v0


@dataclass
class SweepResult:
    """Tip and stage trajectories of a batch of runs. ``tip`` [nrun, n, 3] (m, world), ``stage`` [nrun, n]
    (m), sampled at ``t`` [n] (s, simulated); ``ok`` [nrun] False where a run diverged (its rows are NaN
    from there on); ``labels`` the frequency (Hz) or twist (deg) of each run."""

    t: np.ndarray
    tip: np.ndarray
    stage: np.ndarray
    ok: np.ndarray
    labels: np.ndarray
    frequencies: np.ndarray
    twists: np.ndarray
    integrator: str
    timestep: float
    wall_s: float
    info: dict = field(default_factory=dict)


def slider_inertia(model: mujoco.MjModel, qpos: np.ndarray, joint: str = "stage") -> float:
    """The stage slider's total inertia M[s, s] (armature + everything it carries) at ``qpos``."""
    d = mujoco.MjData(model)
    d.qpos[:] = qpos
    mujoco.mj_forward(model, d)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, d, full)
    dof = model.jnt_dofadr[model.joint(joint).id]
    return float(full[dof, dof])


def run_batch(
    models: Sequence[mujoco.MjModel],
    frequencies: Floats,
    amplitude: float = 0.002,
    settle_s: float = 1.0,
    record_s: float = 0.5,
    sample_every: int = 1,
    integrator: str = "implicitfast",
    nthread: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Run model i at frequency i (one shared size signature); record after ``settle_s``.

    Returns (t [n], tip [nrun, n, 3], stage [nrun, n], ok [nrun], wall seconds).
    """
    nrun = len(models)
    m0 = models[0]
    h = float(m0.opt.timestep)
    if any(float(m.opt.timestep) != h for m in models):
        raise ValueError("run_batch: all models need the same timestep")
    n_total, keep = window(settle_s, record_s, h, sample_every)
    stage_dof = m0.jnt_dofadr[m0.joint("stage").id]
    cache: dict[int, tuple[np.ndarray, float]] = {}
    for m in models:
        if id(m) not in cache:
            q = equilibrium_qpos(m)
            cache[id(m)] = (q, slider_inertia(m, q))
    qpos0 = np.stack([cache[id(m)][0] for m in models])
    masses = [cache[id(m)][1] for m in models]
    qvel0 = np.zeros((nrun, m0.nv))
    for i, f in enumerate(frequencies):
        qvel0[i, stage_dof] = stage_controls(f, amplitude, h, 1, masses[i], integrator)[1]

    def controls(k0: int, n: int) -> np.ndarray:
        ctrl = np.empty((nrun, n, 1))
        for i, f in enumerate(frequencies):
            ctrl[i, :, 0] = stage_controls(f, amplitude, h, n, masses[i], integrator, k0)[0]
        return ctrl

    sd, ok, wall = rollout_batch(models, qpos0, qvel0, controls, n_total, keep, nthread)
    a_tip, a_stage = int(m0.sensor("tip").adr[0]), int(m0.sensor("stage").adr[0])
    tip = sd[:, :, a_tip : a_tip + 3]
    stage = sd[:, :, a_stage]
    # a run that stopped (warnings) or left the scene is marked and blanked from its first bad row
    far = ~np.isfinite(tip).all(axis=2) | (np.linalg.norm(tip, axis=2) > TIP_DIVERGED_M)
    for i in range(nrun):
        if far[i].any() or not ok[i]:
            ok[i] = False
            first = int(np.argmax(far[i])) if far[i].any() else len(keep)
            tip[i, first:] = np.nan
            stage[i, first:] = np.nan
    return keep * h, tip, stage, ok, wall


FREE_BEAM_SETTINGS = SimSettings(settle_s=1.0, record_s=0.5, integrator=DEFAULT_INTEGRATOR, timestep=DEFAULT_TIMESTEP)


def _numerics(settings: SimSettings) -> tuple[str, float]:
    """The settings' integrator and (one) timestep; None: the free beam's defaults."""
    h = settings.timestep
    if isinstance(h, tuple):
        raise ValueError("the free beam takes one timestep for the whole sweep")
    return settings.integrator or DEFAULT_INTEGRATOR, DEFAULT_TIMESTEP if h is None else float(h)


def frequency_sweep(
    beam: BeamModel | str = "prb3",
    frequencies: Floats = tuple(range(1, 46)),
    settings: SimSettings = FREE_BEAM_SETTINGS,
    sample_dt: float | None = None,
    gravity: bool = True,
) -> SweepResult:
    """Steady-state tip trajectories over a frequency sweep (paper Fig. 2f/g), batched on all cores.

    ``settings``: the window, twist, amplitude, integrator, timestep and threads (noise and seed do not apply)."""
    bm = beam_model(beam) if isinstance(beam, str) else beam
    freqs = np.asarray(frequencies, float)
    integrator, timestep = _numerics(settings)
    twist_deg, amplitude = settings.twist_deg, settings.amplitude_m
    settle_s, record_s, nthread = settings.settle_s, settings.record_s, settings.nthread
    model = build_free_beam_spec(bm, twist_deg, integrator, timestep, gravity).compile()
    every = 1 if sample_dt is None else max(1, round(float(sample_dt / timestep)))
    t, tip, stage, ok, wall = run_batch(
        [model] * len(freqs), freqs, amplitude, settle_s, record_s, every, integrator, nthread
    )
    return SweepResult(
        t,
        tip,
        stage,
        ok,
        freqs,
        freqs,
        np.full(len(freqs), twist_deg),
        integrator,
        timestep,
        wall,
        {"model": bm.name, "nv": int(model.nv), "amplitude": amplitude, "gravity": gravity},
    )


def twist_sweep(
    beam: BeamModel | str = "prb3",
    twists: Floats = tuple(range(0, 181, 5)),
    frequency: float = 15.0,
    settings: SimSettings = FREE_BEAM_SETTINGS,
    sample_dt: float | None = None,
    gravity: bool = True,
) -> SweepResult:
    """Tip trajectories over twist angles φ at one frequency (paper Fig. 2c–e), batched on all cores.

    ``settings`` as for :func:`frequency_sweep` (its ``twist_deg`` is replaced by ``twists``). Models of different
    size (PRB3 merges a joint at φ = 0) run in separate batches."""
    bm = beam_model(beam) if isinstance(beam, str) else beam
    tw = np.asarray(twists, float)
    integrator, timestep = _numerics(settings)
    amplitude, settle_s, record_s, nthread = (
        settings.amplitude_m,
        settings.settle_s,
        settings.record_s,
        settings.nthread,
    )
    models = [build_free_beam_spec(bm, float(p), integrator, timestep, gravity).compile() for p in tw]
    every = 1 if sample_dt is None else max(1, round(float(sample_dt / timestep)))
    groups: dict[tuple[int, int], list[int]] = {}
    for i, m in enumerate(models):
        groups.setdefault((m.nq, m.nv), []).append(i)
    tip: np.ndarray | None = None
    stage: np.ndarray | None = None
    ok = np.ones(len(tw), bool)
    wall = 0.0
    t = np.zeros(0)
    for idx in groups.values():
        t, tp, st, okg, w = run_batch(
            [models[i] for i in idx], [frequency] * len(idx), amplitude, settle_s, record_s, every, integrator, nthread
        )
        if tip is None or stage is None:  # every group records the same window
            tip = np.full((len(tw), len(t), 3), np.nan)
            stage = np.full((len(tw), len(t)), np.nan)
        tip[idx], stage[idx], ok[idx] = tp, st, okg
        wall += w
    assert tip is not None and stage is not None  # there is at least one twist
    return SweepResult(
        t,
        tip,
        stage,
        ok,
        tw,
        np.full(len(tw), frequency),
        tw,
        integrator,
        timestep,
        wall,
        {"model": bm.name, "amplitude": amplitude, "gravity": gravity},
    )


@batched(FREE_BEAM)
def run_sweep_task(task: BatchTask) -> list[JobRun]:
    """A sweep's jobs, one compiled model per point, one batch per model shape, timestep, integrator and
    amplitude (PRB3 merges a joint at φ = 0), in this thread: tip and stage on the ``task.sample_dt`` grid."""
    compiled: dict[str, mujoco.MjModel] = {}  # one model (and one rest pose) per point, shared by its frequencies
    for job in task.jobs:
        if job.group not in compiled:
            h = job.timestep or DEFAULT_TIMESTEP
            compiled[job.group] = build_free_beam_spec(job.beam, job.twist_deg, job.integrator, h).compile()
    groups: dict[tuple, list[int]] = {}
    for i, job in enumerate(task.jobs):
        m = compiled[job.group]
        groups.setdefault((m.nq, m.nv, float(m.opt.timestep), job.integrator, job.amplitude_m), []).append(i)
    runs: list[JobRun] = []
    for (_, _, h, integ, amp), idx in groups.items():
        jobs = [task.jobs[i] for i in idx]
        models = [compiled[j.group] for j in jobs]
        every = max(1, round(task.sample_dt / h))
        freqs = [j.frequency_hz for j in jobs]
        t, tip, stage, ok, _ = run_batch(models, freqs, amp, task.settle_s, task.record_s, every, integ, nthread=1)
        for k, job in enumerate(jobs):
            if ok[k]:
                runs.append(JobRun(job.index, True, t, stage=stage[k], tip=tip[k]))
            else:
                runs.append(JobRun(job.index, False, t, reason=unstable_reason(models[k], integ)))
    return sorted(runs, key=lambda r: r.index)


def orbit_axes(tip: np.ndarray) -> tuple[float, float, float, float]:
    """Ellipse-like description of a tip orbit in the x–z plane (⊥ to the beam): (major, minor, tilt_deg,
    signed_area). Axes are full lengths (2·√2·σ of the principal components, exact for an ellipse); the tilt
    is the major axis' angle from x in degrees; the signed area (shoelace over the samples, m², summed over
    the periods in the window) is > 0 for counter-clockwise travel in (x, z) coordinates."""
    p = tip[:, [0, 2]] - np.nanmean(tip[:, [0, 2]], axis=0)
    p = p[np.isfinite(p).all(axis=1)]
    cov = np.cov(p.T)
    evals, evecs = np.linalg.eigh(cov)
    major = 2 * math.sqrt(2 * max(evals[1], 0.0))
    minor = 2 * math.sqrt(2 * max(evals[0], 0.0))
    v = evecs[:, 1]
    tilt = math.degrees(math.atan2(v[1], v[0]))
    tilt = (tilt + 90.0) % 180.0 - 90.0
    x, z = p[:, 0], p[:, 1]
    area = 0.5 * float(np.sum(x * np.roll(z, -1) - np.roll(x, -1) * z))
    return major, minor, tilt, area
