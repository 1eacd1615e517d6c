"""``beambench sweep SWEEP.yaml``: a parameter sweep on the sim backend into one results table."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from beambench.commands import fail
from beambench.common.resources import shipped_names, user_dir

if TYPE_CHECKING:
    from beambench.studies.sweep.run import SweepSpec


def default_table(name: str) -> Path:
    """Where a sweep's table goes without ``--out`` or the file's ``output``: the per-user folder's sweeps/."""
    return user_dir("sweeps") / f"{name}.parquet"


_SWEEP_HELP = f"Sweep YAML, or the name of a shipped sweep file: {shipped_names('sweep')}."
_OUT_HELP = (
    f"Results table (.parquet). Default: the file's `output`, else {default_table('<name>')} (the per-user "
    "folder). An existing table is resumed."
)


def sweep(
    sweep_file: Path = typer.Argument(..., metavar="SWEEP", help=_SWEEP_HELP),
    out: Path = typer.Option(
        None,
        "--out",
        "-o",
        help=_OUT_HELP,
    ),
    workers: int = typer.Option(0, "--workers", "-w", help="Local worker processes (0: all cores)."),
    scheduler: str = typer.Option(
        None,
        "--scheduler",
        help="Run on a Dask cluster: its scheduler address, tcp://HOST:PORT (needs the 'cluster' extra).",
    ),
    cluster: str = typer.Option(
        None,
        "--cluster",
        help="'slurm': start workers as SLURM jobs through "
        "dask-jobqueue (configure queue/account/cores/memory in ~/.config/dask/jobqueue.yaml; "
        "--workers = number of jobs).",
    ),
    batch_size: int = typer.Option(
        0,
        "--batch-size",
        help="Simulations per task (0: the file's batch_size, else 10–50 chosen from the sweep size).",
    ),
    figure: bool = typer.Option(
        True, "--figure/--no-figure", help="Also draw metrics vs the first swept parameter (<table>.png)."
    ),
    dry_run: bool = typer.Option(False, "--dry-run", help="Print the plan (points, done, to do) and exit."),
) -> None:
    """Sweep scene parameters (twist, chirality, gap, stiffness, model …) × frequencies on the simulator.

    Every point's per-step metrics (free beam: tip ellipse major/minor/tilt/sense; contact rig: foot ellipse,
    contacts per cycle, regime) go to one Parquet table, saved as each task finishes. Rerunning the
    same command skips finished points, so an interrupted sweep resumes where it stopped.
    """
    spec = _checked_spec(sweep_file, workers, batch_size, scheduler, cluster)
    out = out or (Path(spec.output) if spec.output else default_table(spec.name))

    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from beambench.common.console import LogProgress, stderr_console
    from beambench.studies.executor import ExecutorError
    from beambench.studies.sweep.figure import plot_sweep
    from beambench.studies.sweep.run import SweepError, run_sweep

    if dry_run:
        _print_plan(spec, out)
        return
    _check_outputs(out)
    console = stderr_console()
    with LogProgress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=False,
    ) as prog:
        task = prog.add_task(f"{spec.name}", total=None)

        def on_start(todo: int, skipped: int, tasks: int, label: str) -> None:
            what = (
                f"{todo} points in {tasks} tasks ({skipped} done before) on {label}"
                if todo
                else f"all {skipped} points done before, nothing to compute"
            )
            prog.update(task, total=todo, description=f"{spec.name}: {what}")

        def progress(done: int, total: int) -> None:
            prog.update(task, completed=done)

        try:
            run = run_sweep(spec, out, workers or None, scheduler, cluster, batch_size or None, progress, on_start)
        except (SweepError, ExecutorError) as exc:
            fail(str(exc))
    t = run.table
    n_bad = int((~t["ok"]).sum()) if "ok" in t.columns else 0
    overhead = ""
    if run.computed and run.wall_s > 0:
        overhead = f", {run.task_compute_s:.1f} s of simulation in {run.wall_s:.1f} s wall"
    typer.echo(
        f"{run.path}: {len(t)} points ({run.computed} computed, {run.skipped} already done"
        f"{', ' + str(n_bad) + ' failed' if n_bad else ''}){overhead}"
    )
    if figure and len(t):
        fig = plot_sweep(t, spec, run.path.with_suffix(".png"))
        if fig is not None:
            typer.echo(f"figure: {fig}")


def register(app: typer.Typer) -> None:
    app.command("sweep")(sweep)


def _checked_spec(
    sweep_file: Path, workers: int, batch_size: int, scheduler: str | None, cluster: str | None
) -> SweepSpec:
    """The sweep file's spec, after the options are checked (one line and exit 2 for anything wrong)."""
    from beambench.studies.executor import MAX_LOCAL_WORKERS
    from beambench.studies.sweep.run import SweepError, load_sweep

    if workers < 0:
        fail(f"--workers = {workers}: must be >= 0")
    if workers > MAX_LOCAL_WORKERS and cluster is None:
        fail(f"--workers = {workers}: at most {MAX_LOCAL_WORKERS} local worker processes")
    if batch_size < 0:
        fail(f"--batch-size = {batch_size}: must be >= 0")
    if scheduler and cluster:
        fail("give either --scheduler or --cluster, not both")
    if cluster and cluster != "slurm":
        fail(f"--cluster = {cluster!r}: only 'slurm' is supported")
    from beambench.common.resources import ShippedFileError, resolve_file

    try:
        spec = load_sweep(resolve_file("sweep", sweep_file))
    except (SweepError, ShippedFileError) as exc:
        fail(str(exc))
    return spec


def _check_outputs(out: Path) -> None:
    """The table, its parts folder and its figure: none a link, in a folder that takes files (one line, exit 2)."""
    from beambench.common.outputs import output_file_problem, output_folder_problem
    from beambench.studies.sweep.run import parts_dir

    names = (out.name, parts_dir(out).name, out.with_suffix(".png").name)
    problem = output_folder_problem(out.parent, names) or output_file_problem(out)
    if problem:
        fail(f"--out: {problem}")


def _print_plan(spec: SweepSpec, out: Path) -> None:
    """``--dry-run``: the points, how many are done and how many to do."""
    from beambench.studies.sweep.run import SweepError, plan, read_table

    try:
        jobs = plan(spec)
        old = read_table(out)
    except SweepError as exc:
        fail(str(exc))
    done = set(old["point_id"]) if "point_id" in old.columns else set()
    todo = sum(j.id not in done for j in jobs)
    typer.echo(
        f"{spec.name}: {spec.scene}, {len(jobs)} points ({len(jobs) - todo} done, {todo} to do), "
        f"axes: {', '.join(spec.axes()) or '(single point)'}; table: {out}"
    )
