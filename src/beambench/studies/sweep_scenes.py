"""How each scene with a batched engine runs a sweep task: one runner per scene, registered with
:func:`batched` against its :class:`~beambench.acquisition.protocol.scenes.SceneInfo` (``batched=True``), fed a typed
:class:`SweepTask`, returning one result row per job with the scene's metrics (:mod:`beambench.analysis`).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from beambench.acquisition.protocol.scenes import CONTACT, FREE_BEAM, SceneInfo

__all__ = ["RUNNERS", "Job", "SweepTask", "batched", "run_task"]


@dataclass(frozen=True)
class Job:
    """One simulation of a sweep: its index in the plan, key, scene parameters and frequency."""

    index: int
    id: str
    point: dict[str, Any]
    frequency_hz: float


@dataclass(frozen=True)
class SweepTask:
    """Jobs one worker simulates together (one batched MuJoCo call per model shape), with the sweep's windows."""

    scene: str
    jobs: tuple[Job, ...]
    settle_s: float
    record_s: float
    sample_dt: float


def _beam(point: dict[str, Any]):
    """The beam model of a point, with its stiffness/damping overrides applied (the beam's own overrides,
    :data:`beambench.studies.unknowns.BEAM_OVERRIDES`, as the fit applies them)."""
    from beambench.sim.models.registry import default_params, is_rod, make_beam_model
    from beambench.studies.unknowns import BEAM_OVERRIDES

    name = point["model"]
    params = default_params(name, point["params"])
    for key in ("youngs_modulus", "beta") if is_rod(name) else ("k", "b"):
        if point.get(key) is not None:
            params = BEAM_OVERRIDES[key](params, point[key])
    return make_beam_model(name, params)


def run_task(task: SweepTask) -> list[dict[str, Any]]:
    """Simulate one task's jobs (in this process, one thread) and return one result row per job."""
    return RUNNERS[task.scene](task)


TaskRunner = Callable[[SweepTask], list[dict[str, Any]]]
RUNNERS: dict[str, TaskRunner] = {}
"""Scene name → how its batched engine runs a task (registered with :func:`batched`)."""


def batched(info: SceneInfo) -> Callable[[TaskRunner], TaskRunner]:
    """Register the task runner of a scene with a batched engine (``info.batched``), once."""

    def add(run: TaskRunner) -> TaskRunner:
        if not info.batched:
            raise ValueError(f"{info.name} declares no batched engine")
        if info.name in RUNNERS:
            raise ValueError(f"{info.name} has a sweep runner already")
        RUNNERS[info.name] = run
        return run

    return add


@batched(FREE_BEAM)
def _run_free_beam(task: SweepTask) -> list[dict[str, Any]]:
    from beambench.sim.scenes.free_beam import build_free_beam_spec, run_batch

    rows: dict[int, dict[str, Any]] = {}
    models, freqs, jobs = [], [], []
    compiled: dict[str, Any] = {}  # one model (and one rest pose) per scene point, shared by its frequencies
    for job in task.jobs:
        index, jid, point, f = job.index, job.id, job.point, job.frequency_hz
        key = json.dumps(point, sort_keys=True)
        if key not in compiled:
            h = point["timestep"] or 1e-4
            compiled[key] = build_free_beam_spec(
                _beam(point), point["twist_deg"] * point["chirality"], point["integrator"], h
            ).compile()
        models.append(compiled[key])
        freqs.append(f)
        jobs.append((index, jid, point, f))
    # one batch per model shape, timestep, integrator and amplitude (PRB3 merges a joint at φ = 0)
    groups: dict[tuple, list[int]] = {}
    for i, m in enumerate(models):
        p = jobs[i][2]
        groups.setdefault((m.nq, m.nv, float(m.opt.timestep), p["integrator"], p["amplitude_mm"]), []).append(i)
    for (_, _, h, integ, amp), idx in groups.items():
        every = max(1, round(task.sample_dt / h))
        t, tip, stage, ok, _ = run_batch(
            [models[i] for i in idx],
            [freqs[i] for i in idx],
            amp * 1e-3,
            task.settle_s,
            task.record_s,
            every,
            integ,
            nthread=1,
        )
        for j, i in enumerate(idx):
            index, jid, point, f = jobs[i]
            metrics = _free_metrics(t, tip[j], stage[j], f) if ok[j] else _why(models[i], integ)
            rows[index] = _row(index, jid, point, f, FREE_BEAM.name, bool(ok[j]), metrics)
    return [rows[i] for i in sorted(rows)]


@batched(CONTACT)
def _run_contact(task: SweepTask) -> list[dict[str, Any]]:
    from beambench.sim.scenes.contact_sweep import contact_sweep
    from beambench.sim.settings import SimSettings

    rows: dict[int, dict[str, Any]] = {}
    groups: dict[str, list[Job]] = {}
    for job in task.jobs:
        groups.setdefault(json.dumps(job.point, sort_keys=True), []).append(job)
    for key, jobs in groups.items():
        point = json.loads(key)
        freqs = [j.frequency_hz for j in jobs]
        sim = SimSettings(
            settle_s=task.settle_s,
            record_s=task.record_s,
            twist_deg=point["twist_deg"] * point["chirality"],
            amplitude_m=point["amplitude_mm"] * 1e-3,
            integrator=point["integrator"],
            timestep=point["timestep"],
            nthread=1,
        )
        r = contact_sweep(_beam(point), freqs, sim, gap_m=point["gap_mm"] * 1e-3, sample_dt=task.sample_dt)
        for i, job in enumerate(jobs):
            index, jid, p, f = job.index, job.id, job.point, job.frequency_hz
            ok = bool(r.ok[i])
            metrics = _contact_metrics(r, i, f, point["amplitude_mm"] * 1e-3) if ok else _why(None, point["integrator"])
            metrics["timestep_s"] = float(r.timesteps[i])
            rows[index] = _row(index, jid, p, f, CONTACT.name, ok, metrics)
    return [rows[i] for i in sorted(rows)]


def _why(model: Any, integrator: str) -> dict[str, Any]:
    """A failed row's reason (beambench.sim.engine.stability; the contact scene's model is not at hand)."""
    from beambench.sim.engine.stability import unstable_reason

    return {"reason": unstable_reason(model, integrator) if model is not None else f"{integrator}: MuJoCo stopped"}


def _row(
    index: int, jid: str, point: dict[str, Any], f: float, scene: str, ok: bool, metrics: dict[str, Any]
) -> dict[str, Any]:
    return {"point": index, "point_id": jid, "scene": scene, **point, "frequency_hz": f, "ok": ok, **metrics}


def _ellipse_cols(prefix: str, t: np.ndarray, xy_mm: np.ndarray, f: float) -> dict[str, Any]:
    from beambench.analysis import fit_ellipse_harmonic
    from beambench.analysis.trajectory import area_per_cycle

    e = fit_ellipse_harmonic(t, xy_mm, f)
    return {
        f"{prefix}_major_mm": e.major,
        f"{prefix}_minor_mm": e.minor,
        f"{prefix}_tilt_deg": e.tilt_deg,
        f"{prefix}_sense": "" if e.clockwise is None else ("cw" if e.clockwise else "ccw"),
        f"{prefix}_ellipse_r2": e.r2,
        f"{prefix}_area_mm2": area_per_cycle(t, xy_mm, f),
    }


def _free_metrics(t: np.ndarray, tip: np.ndarray, stage: np.ndarray, f: float) -> dict[str, Any]:
    """First-harmonic ellipses of the tip path in the (drive = x, up = z) plane, mm (analysis package):
    ``tip_*`` in the lab frame (the end-point trajectory of the paper's Fig. 2c–g) and ``tip_rel_*``
    relative to the stage (the analysis package's convention for mocap sessions)."""
    lab = tip[:, [0, 2]] * 1e3
    rel = np.column_stack([tip[:, 0] - stage, tip[:, 2]]) * 1e3
    return {
        **_ellipse_cols("tip", t, lab, f),
        **_ellipse_cols("tip_rel", t, rel, f),
        "tip_out_of_plane_mm": float(np.ptp(tip[:, 1]) * 1e3),
    }


def _contact_metrics(r: Any, i: int, f: float, amplitude: float) -> dict[str, Any]:
    """Foot ellipse relative to the stage (``foot_rel_*``) and contacts per cycle from the plate's normal
    force (``contacts_per_cycle``, ``regime`` …)."""
    from beambench.analysis import detect_contacts, summarize_contacts

    t = r.t
    stage = amplitude * np.sin(2 * np.pi * f * t)
    rel = np.column_stack([r.foot[i, :, 0] - stage, r.foot[i, :, 2]]) * 1e3
    normal, foot_z = r.contact[i]
    h = float(r.timesteps[i])
    tf = t[0] + np.arange(len(normal)) * h
    c = detect_contacts(tf, np.asarray(normal, float), f, foot_t_s=tf, foot_height_m=np.asarray(foot_z, float))
    s = summarize_contacts(c, f)
    return {
        **_ellipse_cols("foot_rel", t, rel, f),
        "n_contacts": s.n_contacts,
        "contact_frequency_hz": s.contact_frequency_hz,
        "contacts_per_cycle": s.contacts_per_cycle,
        "regime": s.regime,
        "in_contact_fraction": s.in_contact_fraction,
        "peak_normal_n": float(np.max(normal)),
    }
