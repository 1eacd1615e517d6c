"""``beambench bench models``: the model-fidelity ladder (speed vs accuracy, stability map).

Writes ``ladder_table.csv`` (model × integrator × timestep × frequency: tip error, status, wall time),
``ladder_summary.csv``, ``speed_accuracy.png`` and ``stability_map.png`` into ``--out`` (default: ``bench/models``
in the per-user folder).
"""

from __future__ import annotations

import time
from pathlib import Path

import typer

from beambench.commands import fail, sub_app
from beambench.common.resources import user_dir

bench_app = sub_app("Benchmarks of the simulation: beam models, integrators, timesteps.")


def default_out() -> Path:
    """The ladder's folder without ``--out``: ``bench/models`` in the per-user folder."""
    return user_dir("bench") / "models"


_MODELS_HELP = (
    "Run the model-fidelity ladder: each beam model × integrator × timestep on the free-beam scene. "
    "Measures the tip RMS error against a 40-segment-rod reference over 5–45 Hz, the wall time per 10 s "
    "simulated (one thread, median of 3) and the stability (diverged, growing, more than 1 % from converged, "
    "ok); writes the CSVs, the speed-vs-accuracy chart and the stability map."
)


_OUT_HELP = f"Folder for the CSVs and the figures (default: {default_out()}, the per-user folder)."


@bench_app.command("models", help=_MODELS_HELP)
def models(
    quick: bool = typer.Option(
        False,
        "--quick",
        help="A small ladder (4 models: PRB3, two rods and the twins' rod5g; 3 frequencies, short windows): "
        "under 2 minutes on 2 cores. Without it: the full ladder (tens of minutes).",
    ),
    out: Path | None = typer.Option(
        None,
        "--out",
        "-o",
        help=_OUT_HELP,
    ),
    threads: int = typer.Option(0, "--threads", help="Threads for the batched sweeps (0: all cores)."),
) -> None:
    """The fidelity ladder (see ``_MODELS_HELP``)."""
    out = out or default_out()
    from beambench.common.outputs import output_folder_problem

    problem = output_folder_problem(out)  # a link at the folder or inside it is a taken name
    if problem:
        fail(f"--out: {problem}")
    if threads < 0:
        fail(f"--threads = {threads}: must be >= 0")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        fail(f"--out = {str(out)!r}: cannot create ({exc.strerror or exc})")

    from dataclasses import replace

    from rich.console import Console
    from rich.progress import (
        BarColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from beambench.common.console import LogProgress, stderr_console
    from beambench.studies.ladder.figures import write_outputs
    from beambench.studies.ladder.run import (
        FULL,
        QUICK,
        run_ladder,
        summarize,
    )

    cfg = replace(QUICK if quick else FULL, nthread=threads or None)
    console = stderr_console()
    t0 = time.perf_counter()
    with LogProgress(
        TextColumn("[bold]{task.description:<40}"),
        BarColumn(),
        TextColumn("{task.percentage:>3.0f}%"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=False,
    ) as progress:
        task = progress.add_task("ladder", total=1.0)

        def on_progress(desc: str, frac: float) -> None:
            progress.update(task, advance=frac, description=desc)

        table = run_ladder(cfg, on_progress)
        progress.update(task, completed=1.0, description="figures")
        paths = write_outputs(table, out, cfg)
    summary = summarize(table, cfg.error_band)
    _print_summary(summary, Console())
    for name, p in paths.items():
        typer.echo(f"{name}: {p}")
    typer.echo(f"ladder ({cfg.label}) took {time.perf_counter() - t0:.0f} s")


def _print_summary(summary, console) -> None:
    from rich.table import Table

    from beambench.studies.ladder.run import pareto

    t = Table(title="Pareto front (stable over 5–45 Hz): fastest for each error level")
    for col in ("model", "integrator", "dt [s]", "nv", "mean err [mm]", "max err [mm]", "wall s / 10 s"):
        t.add_column(col, justify="right")
    for _, r in pareto(summary).iterrows():
        t.add_row(
            r.model,
            r.integrator,
            f"{r.timestep:g}",
            f"{r.nv:.0f}",
            f"{r.err_mean_mm:.3g}",
            f"{r.err_max_mm:.3g}",
            f"{r.wall_s_per_10s:.3g}",
        )
    console.print(t)


def register(app: typer.Typer) -> None:
    app.add_typer(bench_app, name="bench")
