"""Parameter sweeps on the sim backend: a grid or list of scene parameters × frequencies → one results table.

A sweep file (YAML, validated by :class:`SweepSpec`)::

    name: twist_sweep
    scene: free_beam            # free_beam | contact
    base: {model: prb3, params: paper, twist_deg: 90, amplitude_mm: 2}
    grid:                       # cartesian product of the axes (or `points:` — an explicit list of dicts)
      twist_deg: {start: 0, stop: 180, step: 5}
    frequencies: [15]           # crossed with the grid; a list or {start, stop, step}
    settle_s: 1.0
    record_s: 0.5

Scene parameters (:data:`PARAMETERS`): ``model`` (prb3, rodN …), ``params`` (a set in ``sim_backend/``),
``twist_deg``, ``chirality`` (±1, multiplies the twist), ``gap_mm`` (contact), ``k``/``b`` (PRB3 stiffness and
damping of all five joints), ``youngs_modulus``/``beta`` (segmented rods), ``amplitude_mm``, ``integrator``,
``timestep`` (None: the scene's default — 1e-4 s free, the measured per-frequency choice on the contact rig).

Each point gets the per-step metrics of :mod:`beambench.analysis`: free-beam points the first-harmonic
ellipse of the tip path relative to the stage (major, minor, tilt, sense — paper Fig. 2e), contact points the
foot ellipse and the contacts per drive cycle with their regime (:func:`~beambench.analysis.detect_contacts`).

Points run in tasks of ``batch_size`` simulations (one batched MuJoCo call per model shape) through the
executor seam (:mod:`beambench.studies.executor`: local processes, or Dask). Every finished task's rows are saved
at once (``<table>.parts/``) and merged into the table (Parquet, written atomically) every few seconds and at
the end. Rows are keyed by a hash of each point's parameters, so a rerun skips what is done and an interrupted
sweep resumes; they do not depend on how points were batched or where they ran.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import pandas as pd
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from beambench.acquisition.scenes import CONTACT, FREE_BEAM, SceneInfo, batched_names, foreign_option
from beambench.common.yaml_config import ConfigError, load_yaml_file, validate

SCHEMA = "beambench.sweep/1"

MAX_JOBS = 100_000  # scene points x frequencies: beyond this a sweep file is a typo (a 1e-9 step)


class SweepError(ConfigError):
    """A sweep file or table problem (one line: file, field, reason)."""


class _Model(BaseModel):
    # strict: true is not a number, "5" is not 5; every float finite
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


class Point(_Model):
    """One simulation's scene parameters (everything but the frequency)."""

    model: str = "prb3"
    params: str = "paper"
    twist_deg: float = 90.0
    chirality: Literal[1, -1] = 1
    gap_mm: float = Field(1.0, ge=-2, le=50)
    k: float | None = Field(None, gt=0)
    b: float | None = Field(None, gt=0)
    youngs_modulus: float | None = Field(None, gt=0)
    beta: float | None = Field(None, gt=0)
    amplitude_mm: float = Field(2.0, gt=0, le=10)
    integrator: Literal["euler", "implicitfast", "implicit", "rk4", "discrete"] = "implicitfast"
    timestep: float | None = Field(None, gt=0, le=0.01)

    @model_validator(mode="after")
    def _overrides_fit_model(self) -> Point:
        from beambench.sim.models.registry import is_rod, model_family

        try:
            model_family(self.model)
        except ValueError as exc:  # unknown names: reported by pydantic as the field's error
            raise ValueError(str(exc).removeprefix("sim.")) from None
        rod = is_rod(self.model)
        if rod and (self.k is not None or self.b is not None):
            raise ValueError("k/b set the PRB3 joints; for rods sweep youngs_modulus/beta")
        if not rod and (self.youngs_modulus is not None or self.beta is not None):
            raise ValueError("youngs_modulus/beta set segmented rods; for prb3 sweep k/b")
        return self


PARAMETERS = tuple(Point.model_fields)


def _batched_scene(name: str) -> str:
    known = batched_names()
    if name not in known:
        raise ValueError("Input should be " + " or ".join(repr(n) for n in known))
    return name


# a scene with a batched engine (beambench.acquisition.scenes: free_beam, contact)
SweepScene = Annotated[str, AfterValidator(_batched_scene)]


class Range(_Model):
    """``start``…``stop`` (inclusive) in steps of ``step``."""

    start: float
    stop: float
    step: float = Field(gt=0)

    @model_validator(mode="after")
    def _bounded(self) -> Range:
        n = (self.stop - self.start) / self.step
        if n > MAX_JOBS:
            raise ValueError(f"{n:.3g} values (start/stop/step): more than {MAX_JOBS}")
        return self

    def values(self) -> list[float]:
        n = math.floor((self.stop - self.start) / self.step + 1e-9)
        return [round(self.start + i * self.step, 10) for i in range(n + 1)]


class SweepSpec(_Model):
    """A sweep: scene, base parameters, a grid (cartesian) or list of points, frequencies and windows."""

    name: str = Field("sweep", min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = ""
    scene: SweepScene = "free_beam"
    base: dict[str, Any] = Field(default_factory=dict)
    grid: dict[str, list[Any] | Range] = Field(default_factory=dict)
    points: list[dict[str, Any]] = Field(default_factory=list, max_length=MAX_JOBS)
    frequencies: Annotated[list[float], Field(max_length=MAX_JOBS)] | Range = Field(default_factory=lambda: [15.0])
    settle_s: float = Field(1.0, ge=0, le=60)
    record_s: float = Field(0.5, gt=0, le=60)
    sample_dt: float = Field(1e-3, gt=0, le=0.01)
    batch_size: int | None = Field(None, ge=1, le=1000)
    output: str | None = None

    @field_validator("grid", "points", "base")
    @classmethod
    def _known_names(cls, v: Any) -> Any:
        items = v if isinstance(v, list) else [v]
        for d in items:
            for key in d:
                if key not in PARAMETERS:
                    raise ValueError(f"{key!r} is not a scene parameter (one of {', '.join(PARAMETERS)})")
        return v

    @model_validator(mode="after")
    def _one_form(self) -> SweepSpec:
        if self.grid and self.points:
            raise ValueError("give either grid (a cartesian product) or points (a list), not both")
        given = {*self.base, *self.grid, *(k for p in self.points for k in p)}
        foreign = foreign_option(self.scene, given, "scene")
        if foreign is not None:
            raise ValueError(f"{foreign[0]} {foreign[1]}")
        if any(f <= 0 for f in self.frequency_values()):
            raise ValueError("frequencies must be > 0 Hz")
        n = len(self.frequency_values()) * (len(self.points) or 1)
        for v in self.grid.values():
            n *= max(1, len(v.values()) if isinstance(v, Range) else len(v))
        if n > MAX_JOBS:
            raise ValueError(f"{n:.3g} simulations (grid x frequencies): more than {MAX_JOBS}")
        return self

    def frequency_values(self) -> list[float]:
        return (
            self.frequencies.values() if isinstance(self.frequencies, Range) else [float(f) for f in self.frequencies]
        )

    def scene_points(self) -> list[Point]:
        """Every scene-parameter combination (base, then grid or points on top), validated."""
        if self.points:
            combos = [dict(p) for p in self.points]
        elif self.grid:
            axes = {k: (v.values() if isinstance(v, Range) else list(v)) for k, v in self.grid.items()}
            combos = [dict(zip(axes, vals)) for vals in itertools.product(*axes.values())]
        else:
            combos = [{}]
        return [Point.model_validate({**self.base, **c}) for c in combos]

    def axes(self) -> list[str]:
        """The swept parameter names (grid axes or keys varied in the list), frequency last if it varies."""
        names = list(self.grid) if self.grid else sorted({k for p in self.points for k in p})
        if len(self.frequency_values()) > 1:
            names.append("frequency_hz")
        return names


PROTOCOL_FILE_KEYS = frozenset({"sweep", "rig", "backend", "limits", "sim", "monitors"})


def load_sweep(path: str | Path) -> SweepSpec:
    """Read and validate a sweep file; :class:`SweepError` names the file and the field."""
    data, _ = load_yaml_file(path, SweepError)
    if isinstance(data, dict) and PROTOCOL_FILE_KEYS & set(data) and not {"scene", "grid", "points"} & set(data):
        raise SweepError(
            str(path),
            "(file)",
            reason=f"this is a protocol file (it has {sorted(PROTOCOL_FILE_KEYS & set(data))[0]}): "
            "run it with `beambench run`, not `beambench sweep`",
        )
    spec = validate(SweepSpec, data, str(path), SweepError, what="sweep fields")
    try:
        spec.scene_points()
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(x) for x in err["loc"] if not str(x).startswith("function-")) or "(top level)"
        msg = "unknown field" if err["type"] == "extra_forbidden" else err["msg"].removeprefix("Value error, ")
        raise SweepError(f"{path}: {loc}: {msg}") from None
    return spec


# ------------------------------------------------------------------------------------------------ plan
def point_id(scene: str, point: Point, frequency: float, spec: SweepSpec) -> str:
    """Stable key of one simulation: a hash of everything that determines its result."""
    key = {
        "scene": scene,
        **point.model_dump(),
        "frequency_hz": float(frequency),
        "settle_s": spec.settle_s,
        "record_s": spec.record_s,
        "sample_dt": spec.sample_dt,
    }
    text = json.dumps(key, sort_keys=True, default=repr)
    return hashlib.sha1(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Job:
    """One simulation of a sweep: its index in the plan, key, scene parameters and frequency."""

    index: int
    id: str
    point: dict[str, Any]
    frequency_hz: float


def plan(spec: SweepSpec) -> list[Job]:
    """Every (scene point × frequency) of the sweep, in table order."""
    jobs: list[Job] = []
    for p in spec.scene_points():
        for f in spec.frequency_values():
            jobs.append(Job(len(jobs), point_id(spec.scene, p, f, spec), p.model_dump(), float(f)))
    return jobs


def _group_key(job: Job) -> tuple:
    """Jobs that can share one batched MuJoCo call sort next to each other."""
    p = job.point
    return (
        p["model"],
        p["params"],
        p["integrator"],
        str(p["timestep"]),
        p["twist_deg"] * p["chirality"] == 0,
        p["gap_mm"],
        p["twist_deg"] * p["chirality"],
        job.index,
    )


def make_tasks(spec: SweepSpec, jobs: list[Job], size: int) -> list[dict[str, Any]]:
    """Cut ``jobs`` into tasks of ``size`` (grouped so a task's simulations batch well). A task is a plain
    dict (picklable for any executor)."""
    from beambench.studies.executor import chunks

    ordered = sorted(jobs, key=_group_key)
    common = {"scene": spec.scene, "settle_s": spec.settle_s, "record_s": spec.record_s, "sample_dt": spec.sample_dt}
    return [
        {**common, "jobs": [(j.index, j.id, j.point, j.frequency_hz) for j in chunk]} for chunk in chunks(ordered, size)
    ]


# ------------------------------------------------------------------------------------------- simulation
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


def run_task(task: dict[str, Any]) -> list[dict[str, Any]]:
    """Simulate one task's jobs (in this process, one thread) and return one result row per job."""
    return _RUNNERS[task["scene"]](task)


TaskRunner = Callable[[dict[str, Any]], list[dict[str, Any]]]
_RUNNERS: dict[str, TaskRunner] = {}  # scene name → how its batched engine runs a task


def _runs(info: SceneInfo) -> Callable[[TaskRunner], TaskRunner]:
    """Register the task runner of a scene with a batched engine (``info.batched``)."""

    def add(run: TaskRunner) -> TaskRunner:
        if not info.batched:
            raise ValueError(f"{info.name} declares no batched engine")
        _RUNNERS[info.name] = run
        return run

    return add


@_runs(FREE_BEAM)
def _run_free_beam(task: dict[str, Any]) -> list[dict[str, Any]]:
    from beambench.sim.scenes.free_beam import build_free_beam_spec, run_batch

    rows: dict[int, dict[str, Any]] = {}
    models, freqs, jobs = [], [], []
    compiled: dict[str, Any] = {}  # one model (and one rest pose) per scene point, shared by its frequencies
    for index, jid, point, f in task["jobs"]:
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
        every = max(1, round(task["sample_dt"] / h))
        t, tip, stage, ok, _ = run_batch(
            [models[i] for i in idx],
            [freqs[i] for i in idx],
            amp * 1e-3,
            task["settle_s"],
            task["record_s"],
            every,
            integ,
            nthread=1,
        )
        for j, i in enumerate(idx):
            index, jid, point, f = jobs[i]
            metrics = _free_metrics(t, tip[j], stage[j], f) if ok[j] else _why(models[i], integ)
            rows[index] = _row(index, jid, point, f, FREE_BEAM.name, bool(ok[j]), metrics)
    return [rows[i] for i in sorted(rows)]


@_runs(CONTACT)
def _run_contact(task: dict[str, Any]) -> list[dict[str, Any]]:
    from beambench.sim.scenes.contact_sweep import contact_sweep
    from beambench.sim.settings import SimSettings

    rows: dict[int, dict[str, Any]] = {}
    groups: dict[str, list[tuple]] = {}
    for job in task["jobs"]:
        p = dict(job[2])
        groups.setdefault(json.dumps(p, sort_keys=True), []).append(job)
    for key, jobs in groups.items():
        point = json.loads(key)
        freqs = [j[3] for j in jobs]
        sim = SimSettings(
            settle_s=task["settle_s"],
            record_s=task["record_s"],
            twist_deg=point["twist_deg"] * point["chirality"],
            amplitude_m=point["amplitude_mm"] * 1e-3,
            integrator=point["integrator"],
            timestep=point["timestep"],
            nthread=1,
        )
        r = contact_sweep(_beam(point), freqs, sim, gap_m=point["gap_mm"] * 1e-3, sample_dt=task["sample_dt"])
        for i, (index, jid, p, f) in enumerate(jobs):
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


# ------------------------------------------------------------------------------------------------ table
def read_table(path: str | Path) -> pd.DataFrame:
    """A sweep table (empty if the file does not exist)."""
    p = Path(path)
    if not p.exists():
        return pd.DataFrame()
    import pyarrow as pa

    try:
        return pd.read_parquet(p)
    except (OSError, ValueError, pa.ArrowException) as exc:
        raise SweepError(f"{p}: not a readable sweep table ({exc})") from None


def write_table(df: pd.DataFrame, path: str | Path, spec: SweepSpec) -> None:
    """Write atomically (temp file + rename): a killed sweep leaves the last complete table."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    table = pa.Table.from_pandas(df, preserve_index=False)
    meta = dict(table.schema.metadata or {})
    meta[b"beambench"] = json.dumps({"schema": SCHEMA, "sweep": spec.name, "scene": spec.scene}).encode()
    table = table.replace_schema_metadata(meta)
    tmp = p.with_name(p.name + ".tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, p)


def _ordered(rows: list[dict[str, Any]], jobs: list[Job]) -> pd.DataFrame:
    order = {j.id: j.index for j in jobs}
    df = pd.DataFrame(rows)
    if df.empty:
        return df
    df = df.drop_duplicates("point_id", keep="first")
    df["point"] = [order.get(i, -1) for i in df["point_id"]]
    df["_other"] = df["point"] < 0
    df = df.sort_values(["_other", "point", "point_id"], kind="stable").drop(columns="_other")
    return df.reset_index(drop=True)


def parts_dir(out: Path) -> Path:
    """Where finished tasks' rows wait (one small Parquet file each) until merged into the table."""
    return out.with_name(out.name + ".parts")


def _read_done(out: Path) -> list[dict[str, Any]]:
    """Rows of the table and of any task files a previous (interrupted) run left beside it."""
    frames = [read_table(out)]
    part_dir = parts_dir(out)
    if part_dir.is_dir():
        frames += [read_table(f) for f in sorted(part_dir.glob("*.parquet"))]
    frames = [f for f in frames if not f.empty]
    for f in frames:
        if "point_id" not in f.columns:
            raise SweepError(f"{out}: not a sweep table (no point_id column)")
    if not frames:
        return []
    return [{str(k): v for k, v in r.items()} for r in pd.concat(frames, ignore_index=True).to_dict("records")]


@dataclass
class SweepRun:
    """What :func:`run_sweep` did: the table, its path, how many points it computed and skipped."""

    table: pd.DataFrame
    path: Path
    computed: int
    skipped: int
    tasks: int
    wall_s: float
    task_compute_s: float  # wall seconds spent inside tasks, summed over workers
    task_cpu_s: float = 0.0  # CPU seconds of the workers inside tasks


MERGE_EVERY_S = 10.0  # the table is rewritten at most this often while a sweep runs (and at its end)


def run_sweep(
    spec: SweepSpec,
    out: str | Path,
    workers: int | None = None,
    scheduler: str | None = None,
    cluster: str | None = None,
    batch_size: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    on_start: Callable[[int, int, int, str], None] | None = None,
) -> SweepRun:
    """Run the points of ``spec`` not yet in the table at ``out``; returns the complete table.

    Each finished task's rows are saved at once as a small file in ``<out>.parts/`` and merged into the table
    every ``MERGE_EVERY_S`` and at the end, so a kill loses at most the tasks still running.
    ``progress(done, total)`` after each task; ``on_start(todo, skipped, tasks, executor label)`` first."""
    from beambench.studies.executor import batch_size as auto_size
    from beambench.studies.executor import make_executor, run_tasks

    out = Path(out)
    if out.suffix != ".parquet":
        raise SweepError(f"--out = {str(out)!r}: the results table is a .parquet file")
    jobs = plan(spec)
    rows = _read_done(out)
    done_ids = {r["point_id"] for r in rows}
    todo = [j for j in jobs if j.id not in done_ids]
    part_dir = parts_dir(out)
    t0 = time.perf_counter()
    last_merge = t0
    compute = cpu = 0.0
    done = 0
    n_tasks = 0

    def merge() -> None:
        write_table(_ordered(rows, jobs), out, spec)
        if part_dir.is_dir():  # everything in it is in the table now (and a killed write's .tmp is junk)
            shutil.rmtree(part_dir)

    if todo:

        def finished(task: dict[str, Any], result: tuple[list[dict[str, Any]], float, float]) -> None:
            nonlocal done, compute, cpu, last_merge
            new, secs, cpu_s = result
            part_dir.mkdir(parents=True, exist_ok=True)
            write_table(pd.DataFrame(new), part_dir / f"{new[0]['point_id']}_{len(new)}.parquet", spec)
            rows.extend(new)
            compute += secs
            cpu += cpu_s
            done += len(new)
            if time.perf_counter() - last_merge > MERGE_EVERY_S:
                merge()
                last_merge = time.perf_counter()
            if progress is not None:
                progress(done, len(todo))

        with make_executor(workers, scheduler, cluster, preload=(__name__,)) as pool:
            size = batch_size or spec.batch_size or auto_size(len(todo), pool.workers)
            tasks = make_tasks(spec, todo, size)
            n_tasks = len(tasks)
            if on_start is not None:
                on_start(len(todo), len(jobs) - len(todo), n_tasks, pool.label)
            try:
                run_tasks(pool.executor, timed_task, tasks, finished)
            finally:
                merge()
    else:
        if on_start is not None:
            on_start(0, len(jobs), 0, "")  # no executor: nothing to compute
        if not out.exists() or part_dir.is_dir():
            merge()
    table = read_table(out)
    return SweepRun(table, out, len(todo), len(jobs) - len(todo), n_tasks, time.perf_counter() - t0, compute, cpu)


def timed_task(task: dict[str, Any]) -> tuple[list[dict[str, Any]], float, float]:
    """:func:`run_task` with the wall and CPU seconds it took in the worker (for the overhead figures)."""
    t0, c0 = time.perf_counter(), time.process_time()
    rows = run_task(task)
    return rows, time.perf_counter() - t0, time.process_time() - c0


def run_local(spec: SweepSpec) -> pd.DataFrame:
    """All points in this process, no executor, no file (for notebooks and checks)."""
    jobs = plan(spec)
    rows: list[dict[str, Any]] = []
    for task in make_tasks(spec, jobs, spec.batch_size or 50):
        rows.extend(run_task(task))
    return _ordered(rows, jobs)
