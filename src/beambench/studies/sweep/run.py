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

from beambench.acquisition.protocol.scenes import batched_names, foreign_option
from beambench.common.yaml_config import ConfigError, load_yaml_file, validate
from beambench.studies.sweep.task import Job, SweepTask, run_task

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


# a scene with a batched engine (beambench.acquisition.protocol.scenes: free_beam, contact)
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
        points = spec.scene_points()
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(x) for x in err["loc"] if not str(x).startswith("function-")) or "(top level)"
        msg = "unknown field" if err["type"] == "extra_forbidden" else err["msg"].removeprefix("Value error, ")
        raise SweepError(f"{path}: {loc}: {msg}") from None
    _check_parameter_sets(points, path)
    return spec


def _check_parameter_sets(points: list[Point], path: str | Path) -> None:
    """Every point's parameter set exists for its model (else the workers would fail one by one)."""
    from beambench.sim.models.params import ParamsError
    from beambench.sim.models.registry import default_params

    for model, params in sorted({(p.model, p.params) for p in points}):
        try:
            default_params(model, params)
        except ParamsError as exc:
            raise SweepError(f"{path}: {str(exc).removeprefix('sim.')}") from None


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


def make_tasks(spec: SweepSpec, jobs: list[Job], size: int) -> list[SweepTask]:
    """Cut ``jobs`` into tasks of ``size`` (grouped so a task's simulations batch well; picklable for any
    executor)."""
    from beambench.studies.executor import chunks

    ordered = sorted(jobs, key=_group_key)
    return [
        SweepTask(spec.scene, tuple(chunk), spec.settle_s, spec.record_s, spec.sample_dt)
        for chunk in chunks(ordered, size)
    ]


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

        def finished(task: SweepTask, result: tuple[list[dict[str, Any]], float, float]) -> None:
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


def timed_task(task: SweepTask) -> tuple[list[dict[str, Any]], float, float]:
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
