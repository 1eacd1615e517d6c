"""How a sweep task runs: the scene's batched engine (registered in its own module with
:func:`beambench.sim.scenes.batched`) simulates the task's jobs and returns standard channels (tip, stage, foot,
the plate's normal force); the metrics are computed here from the channels a run carries (:mod:`beambench.analysis`),
with no code per scene. The MuJoCo side is imported when a task runs, so validating a sweep file needs no MuJoCo.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from beambench.sim.models.beam import BeamModel
    from beambench.sim.scenes.registry import BatchJob, ContactTrace, JobRun

__all__ = ["Job", "SweepTask", "metrics", "run_task"]


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


def _beam(point: dict[str, Any]) -> BeamModel:
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
    """Simulate one task's jobs (in this process, one thread) with the scene's batched engine and return one
    result row per job: the point, the frequency and the metrics of the channels the scene's runs carry."""
    from beambench.sim.scenes import BatchTask, batch_engine

    batch = BatchTask(_batch_jobs(task.jobs), task.settle_s, task.record_s, task.sample_dt)
    runs = {run.index: run for run in batch_engine(task.scene)(batch)}
    rows = []
    for job in sorted(task.jobs, key=lambda j: j.index):
        run = runs[job.index]
        rows.append(_row(job.index, job.id, job.point, job.frequency_hz, task.scene, run.ok, metrics(run, job)))
    return rows


def _batch_jobs(jobs: tuple[Job, ...]) -> tuple[BatchJob, ...]:
    """The engine's view of the jobs: the beam of each point built once (its overrides applied), the drive in SI."""
    from beambench.sim.scenes import BatchJob

    beams: dict[str, BeamModel] = {}
    out = []
    for job in jobs:
        p = job.point
        group = json.dumps(p, sort_keys=True)
        if group not in beams:
            beams[group] = _beam(p)
        out.append(
            BatchJob(
                index=job.index,
                group=group,
                beam=beams[group],
                frequency_hz=job.frequency_hz,
                twist_deg=p["twist_deg"] * p["chirality"],
                amplitude_m=p["amplitude_mm"] * 1e-3,
                integrator=p["integrator"],
                timestep=p["timestep"],
                point=p,
            )
        )
    return tuple(out)


def metrics(run: JobRun, job: Job) -> dict[str, Any]:
    """A run's metrics from its standard channels (:class:`beambench.sim.scenes.JobRun`), the same for every scene:
    a tip path gives ``tip_*`` (lab frame) and ``tip_rel_*`` (relative to the stage) ellipses and the out-of-plane
    travel, a foot path the ``foot_rel_*`` ellipse, a contact trace the contacts per cycle and their regime; a
    failed run its ``reason``; ``timestep_s`` when the scene chose one per job."""
    f = job.frequency_hz
    out: dict[str, Any] = {}
    if not run.ok:
        out["reason"] = run.reason
    else:
        if run.tip is not None and run.stage is not None:
            out.update(_free_metrics(run.t, run.tip, run.stage, f))
        if run.foot is not None and run.stage is not None:
            rel = np.column_stack([run.foot[:, 0] - run.stage, run.foot[:, 2]]) * 1e3
            out.update(_ellipse_cols("foot_rel", run.t, rel, f))
        if run.contact is not None:
            out.update(_contact_metrics(run.contact, f))
    if run.timestep_s is not None:
        out["timestep_s"] = float(run.timestep_s)
    return out


def _row(
    index: int, jid: str, point: dict[str, Any], f: float, scene: str, ok: bool, metrics: dict[str, Any]
) -> dict[str, Any]:
    return {"point": index, "point_id": jid, "scene": scene, **point, "frequency_hz": f, "ok": ok, **metrics}


def _ellipse_cols(prefix: str, t: np.ndarray, xy_mm: np.ndarray, f: float) -> dict[str, Any]:
    from beambench.analysis.trajectory import area_per_cycle, fit_ellipse_harmonic

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


def _contact_metrics(trace: ContactTrace, f: float) -> dict[str, Any]:
    """Contacts per cycle from the plate's normal force at every step (``contacts_per_cycle``, ``regime`` …)."""
    from beambench.acquisition.forces.contact_events import detect_contacts, summarize_contacts

    normal = trace.normal
    c = detect_contacts(trace.t, normal, f, foot_t_s=trace.t, foot_height_m=trace.foot_z)
    s = summarize_contacts(c, f)
    return {
        "n_contacts": s.n_contacts,
        "contact_frequency_hz": s.contact_frequency_hz,
        "contacts_per_cycle": s.contacts_per_cycle,
        "regime": s.regime,
        "in_contact_fraction": s.in_contact_fraction,
        "peak_normal_n": float(np.max(normal)),
    }
