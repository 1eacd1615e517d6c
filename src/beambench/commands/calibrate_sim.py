"""``beambench calibrate sim [SESSION.h5] [--targets TARGETS.yaml]``: fit the twin to a measured sweep or to
published numbers (:mod:`beambench.studies.calibration.search`). The last stdout line is the calibrated protocol's path."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, NoReturn

import typer


def _fail(message: str) -> NoReturn:
    typer.echo(f"beambench: error: {message}", err=True)
    raise typer.Exit(2)


def default_out() -> Path:
    """A per-user folder (``$XDG_DATA_HOME/beambench/calibration``, else ``~/.local/share/...``); never the
    repository or the installed package."""
    root = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(root) / "beambench" / "calibration"


def sim(
    session: Annotated[
        Path | None, typer.Argument(metavar="[SESSION]", help="A measured (or twin-made) session .h5.")
    ] = None,
    targets: Annotated[
        Path | None,
        typer.Option(
            "--targets", help="Targets YAML instead of a session, e.g. calibration/paper_contact_targets.yaml."
        ),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            "-o",
            help="Output folder (default: a per-user folder, ~/.local/share/beambench/calibration). "
            "Re-using it resumes a killed run.",
        ),
    ] = None,
    workers: Annotated[
        int | None, typer.Option("--workers", help="Local worker processes (default: all cores).")
    ] = None,
    scheduler: Annotated[
        str | None, typer.Option("--scheduler", help="Dask scheduler address, e.g. tcp://host:8786.")
    ] = None,
    budget_s: Annotated[float, typer.Option("--budget-s", help="Wall-time budget of the search (s).")] = 540.0,
    quick: Annotated[bool, typer.Option("--quick", help="A smaller, faster search (smoke runs).")] = False,
    name: Annotated[
        str | None, typer.Option("--name", help="Output name (default: <session or targets>_calibrated).")
    ] = None,
    free: Annotated[
        str | None,
        typer.Option(
            "--free",
            help="Comma-separated unknowns to fit instead of the rig's default set (contact rig: "
            "b_scale,preload_mm,friction_scale), e.g. b_scale,preload_mm,friction_scale,frame_mass_g "
            "(contact rig unknowns: k_scale, b_scale, preload_mm, friction_scale, frame_mass_g, mass_dx_mm; "
            "the others stay at the prior set's values).",
        ),
    ] = None,
) -> None:
    """Fit the twin's unknowns so that it reproduces a session's per-step results or a targets file; writes a
    runnable protocol carrying the calibrated parameters and a report beside it."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from beambench.common.errors import BeambenchError
    from beambench.studies.calibration.search import SearchSettings, calibrate, get_rig
    from beambench.studies.calibration.targets import load_targets, session_targets
    from beambench.studies.executor import ExecutorError

    if (session is None) == (targets is None):
        _fail("give a SESSION file or --targets FILE (one of them)")
    if not budget_s > 0:
        _fail(f"--budget-s = {budget_s:g}: must be > 0")
    if workers is not None and workers < 1:
        _fail(f"--workers = {workers}: must be >= 1")
    try:
        tg = session_targets(session) if session is not None else load_targets(targets)  # type: ignore[arg-type]
        get_rig(tg.rig)
    except BeambenchError as exc:
        _fail(str(exc))
    stem = (session or targets).stem  # type: ignore[union-attr]
    name = name or f"{stem}_calibrated"
    out_dir = out or default_out()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _fail(f"--out {out_dir}: cannot create ({exc.strerror or exc})")
    chosen = tuple(n.strip() for n in free.split(",") if n.strip()) if free is not None else None
    if chosen is not None:
        known = {u.name for u in get_rig(tg.rig).unknowns}
        bad = [n for n in chosen if n not in known]
        if not chosen or bad:
            _fail(f"--free {free}: {tg.rig} rig unknowns are {', '.join(sorted(known))}")
    settings = (
        SearchSettings.quick(budget_s=min(budget_s, 150.0), free=chosen)
        if quick
        else SearchSettings(budget_s=budget_s, free=chosen)
    )
    console = Console(stderr=True)
    cols = (
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed} runs"),
        TimeElapsedColumn(),
    )
    try:
        with Progress(*cols, console=console, transient=False) as progress:
            result = calibrate(
                tg, out_dir, name, workers=workers, scheduler=scheduler, settings=settings, progress=progress
            )
    except (BeambenchError, ExecutorError) as exc:
        _fail(str(exc))
    s = result.summary
    console.print(
        f"objective {result.j:.4f}; "
        + ", ".join(f"{k} {v:.4g}" for k, v in result.values.items())
        + "; twin "
        + ", ".join(f"{k} {v}" for k, v in s.items() if k != "map" and not isinstance(v, dict))
        + f"; {result.evaluations} runs ({result.reused} re-used), {result.wall_s:.0f} s; report {result.report}",
        soft_wrap=True,
    )
    typer.echo(str(result.protocol))


def register_sim(sub: typer.Typer) -> None:
    """Add ``beambench calibrate sim`` to the ``calibrate`` sub-app."""
    sub.command("sim")(sim)
