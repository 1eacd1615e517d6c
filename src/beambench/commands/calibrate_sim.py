"""``beambench calibrate sim [SESSION.h5] [--targets TARGETS.yaml]``: fit the twin to a measured sweep or to
published numbers (:mod:`beambench.studies.twin_calibration`). The last stdout line is the calibrated protocol's path;
the last stderr line the verdict (every target met, or the misses with what limits them): :data:`EPILOG`."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer
from typer.core import TyperCommand, TyperOption

from beambench.commands import EXIT_FAULT, EXIT_MISSED, EXIT_OK, EXIT_STOPPED, EXIT_USAGE

EPILOG = (
    f"Exit status: {EXIT_OK} written, every target met within its tolerance; {EXIT_FAULT} an error during the "
    f"search; {EXIT_USAGE} bad input (one line, nothing written); {EXIT_STOPPED} stopped (Ctrl-C: the evaluation "
    "log is kept, the same command with the same --out resumes); "
    f"{EXIT_MISSED} written, but not within tolerance (the last line names each missed target, the twin's value "
    "and the unknown that limits it: one at its bound, or no unknown moves it far enough). Every command's codes: "
    "docs/commands.md, 'Exit codes'. Tolerances: the targets file's tolerance_hz (transitions, default ± 2 Hz) or "
    "tolerance_fraction (walker speeds, default ± 30 %); a tangential sign must match."
)


FREE_HELP = (
    "Comma-separated unknowns to fit instead of the rig's default set; the others stay at the prior set's values."
)


class _SimCommand(TyperCommand):
    """``calibrate sim`` whose ``--free`` and ``--quick`` help list each rig's unknowns and quick budget from the
    calibration registry, imported only when the help is shown (it costs seconds: every other command starts without it)."""

    def format_help(self, ctx: Any, formatter: Any) -> None:  # typer's own (vendored) click types
        from beambench.studies.twin_calibration import quick_help, unknowns_help

        for param in self.params:
            if param.name == "free" and isinstance(param, TyperOption):
                param.help = f"{FREE_HELP} Unknowns: {unknowns_help()}."
            if param.name == "quick" and isinstance(param, TyperOption):
                param.help = quick_help()  # from each rig's quick budget: the one figure, never a copy
        super().format_help(ctx, formatter)


def _fail(message: str) -> NoReturn:
    typer.echo(f"beambench: error: {message}", err=True)
    raise typer.Exit(EXIT_USAGE)


def _interrupted(log: Path | None) -> NoReturn:
    """One line saying where the finished evaluations are and how to resume; exit :data:`EXIT_STOPPED` (as every
    command stopped by Ctrl-C). ``log`` is None when the stop came before the log was named."""
    import contextlib
    import shlex
    import sys

    kept = sum(1 for _ in log.open("rb")) if log is not None and log.is_file() else 0
    again = shlex.join(["beambench", *sys.argv[1:]]) if sys.argv[1:2] == ["calibrate"] else "the same command"
    where = f"{kept} evaluations kept in {log}" if log is not None else "before its first evaluation"
    with contextlib.suppress(OSError):  # a closed terminal (SIGHUP) cannot take it: the exit code still tells
        typer.echo(
            f"beambench: calibration interrupted: {where}; to resume, run {again} again (same --out and --name): "
            "they are reused",
            err=True,
        )
    raise typer.Exit(EXIT_STOPPED)


class _Stops:
    """The stop signals ``calibrate sim`` got, in order, and whether one interrupts now. While the command imports
    and checks its inputs a stop is only recorded: an exception raised there would land inside a module's init or
    a dataclass's generated code, where it may be swallowed or turned into another error. :meth:`arm` (before the
    first evaluation) is the one place a recorded stop becomes the ``KeyboardInterrupt`` that stops the
    calibration; armed, the first stop raises at once (the search waits on its workers: its pool stops them and
    keeps the log), later ones are only counted (a second Ctrl-C cannot cut the workers' shutdown short)."""

    def __init__(self) -> None:
        self.got: list[int] = []
        self.armed = False
        self.raised = False

    def take(self, signum: int) -> None:
        """A stop signal came (the handler): recorded; the first one since :meth:`arm` raises."""
        self.got.append(signum)
        if self.armed and not self.raised:
            self.raised = True
            raise KeyboardInterrupt

    def arm(self) -> None:
        """From now on a stop interrupts; one already recorded (or held while the command line imported) does now."""
        from beambench.common import early_signals

        self.got += early_signals.take()
        self.armed = True  # first: a stop from here on raises in the handler, none falls between
        if self.got and not self.raised:
            self.raised = True
            raise KeyboardInterrupt


@contextmanager
def _interrupt_on_signals() -> Iterator[_Stops]:
    """While inside, the stop signals are :class:`_Stops`' (armed, they interrupt the calibration as Ctrl-C does),
    taken as ``run`` takes them: SIGINT, SIGTERM and SIGQUIT always — also where a shell started the command as a
    background job, which ignores SIGINT —, the others where their disposition is the default. After, they stay
    ignored when this is the command line (it is about to say its last line and exit); called in-process (a
    test), the handlers are put back."""
    import signal
    import threading

    from beambench.acquisition.stop_signals import ALWAYS_SIGNALS, DEFAULT_SIGNALS
    from beambench.commands import STANDALONE

    stops = _Stops()
    if threading.current_thread() is not threading.main_thread():
        yield stops
        return

    def handler(signum: int, frame: object) -> None:
        stops.take(signum)

    taken = [
        s for s in ALWAYS_SIGNALS + DEFAULT_SIGNALS if s in ALWAYS_SIGNALS or signal.getsignal(s) is signal.SIG_DFL
    ]
    previous: dict[int, Any] = {}
    try:
        for signum in taken:  # unarmed: a stop meanwhile is recorded, never raised here
            previous[signum] = signal.signal(signum, handler)
        yield stops
    finally:
        stops.armed = False  # the command has decided how it ends: a stop from here is only counted
        for signum, before in previous.items():
            signal.signal(signum, signal.SIG_IGN if STANDALONE["process"] or before is None else before)


def default_out() -> Path:
    """The per-user folder's ``calibration/`` (``$BEAMBENCH_USER_DIR`` if set); never the checkout or the package."""
    from beambench.common.resources import user_dir

    return user_dir("calibration")


def _shipped_targets() -> str:
    from beambench.common.resources import shipped_names

    return shipped_names("targets")


def sim(
    session: Annotated[
        Path | None, typer.Argument(metavar="[SESSION]", help="A measured (or twin-made) session .h5.")
    ] = None,
    targets: Annotated[
        Path | None,
        typer.Option(
            "--targets",
            help=f"Targets YAML instead of a session, or the name of a shipped targets file: {_shipped_targets()}.",
        ),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            "-o",
            help=f"Output folder (default: {default_out()}, the per-user folder). Re-using it resumes a killed run.",
        ),
    ] = None,
    workers: Annotated[
        int | None, typer.Option("--workers", help="Local worker processes (default: all cores).")
    ] = None,
    scheduler: Annotated[
        str | None, typer.Option("--scheduler", help="Dask scheduler address, e.g. tcp://host:8786.")
    ] = None,
    budget_s: Annotated[
        float,
        typer.Option(
            "--budget-s",
            help="Budget of the search (s of modelled time: each run's simulated seconds at its measured stepping cost, on the workers; about the wall time on idle cores).",
        ),
    ] = 540.0,
    quick: Annotated[bool, typer.Option("--quick", help="A smaller, faster search.")] = False,
    name: Annotated[
        str | None, typer.Option("--name", help="Output name (default: <session or targets>_calibrated).")
    ] = None,
    free: Annotated[
        str | None,
        typer.Option(
            "--free",
            help=FREE_HELP,  # completed from the unknown registry when the help is shown (_SimCommand)
        ),
    ] = None,
) -> None:
    """Fit the twin's unknowns so that it reproduces a session's per-step results or a targets file; writes a
    runnable protocol carrying the calibrated parameters and a report beside it, and says for every target
    whether the twin reached it."""
    log: list[Path] = []  # the evaluation log, once named
    with _interrupt_on_signals() as stops:
        try:
            _sim(session, targets, out, workers, scheduler, budget_s, quick, name, free, log, stops)
        except KeyboardInterrupt:  # a stop signal, from the first line on: every finished evaluation is kept
            _interrupted(log[0] if log else None)
        except Exception:
            if stops.got:  # what the interrupt became where it landed (a cleanup that turned it into an error)
                _interrupted(log[0] if log else None)
            raise
        if stops.got:  # a stop that landed where it could not raise (a cleanup that swallowed it): still said
            _interrupted(log[0] if log else None)


def _sim(
    session: Path | None,
    targets: Path | None,
    out: Path | None,
    workers: int | None,
    scheduler: str | None,
    budget_s: float,
    quick: bool,
    name: str | None,
    free: str | None,
    log: list[Path],
    stops: _Stops,
) -> None:
    """The body of :func:`sim`; ``log`` gets the evaluation log's path as soon as it is known; ``stops`` is armed
    once the inputs are checked, before anything is written."""
    from dataclasses import replace

    from rich.progress import BarColumn, SpinnerColumn, TextColumn, TimeElapsedColumn

    from beambench.common.console import LogProgress, stderr_console
    from beambench.common.errors import BeambenchError
    from beambench.common.names import check_name
    from beambench.common.resources import resolve_file
    from beambench.studies.executor import MAX_LOCAL_WORKERS, ExecutorError
    from beambench.studies.twin_calibration import SearchSettings, calibrate, get_rig, write_report
    from beambench.studies.twin_calibration.rig import load_targets, session_targets

    if (session is None) == (targets is None):
        _fail("give a SESSION file or --targets FILE (one of them)")
    if not budget_s > 0:
        _fail(f"--budget-s = {budget_s:g}: must be > 0")
    if workers is not None and not 1 <= workers <= MAX_LOCAL_WORKERS:
        _fail(f"--workers = {workers}: must be 1 to {MAX_LOCAL_WORKERS} (local worker processes)")
    try:
        tg = session_targets(session) if session is not None else load_targets(resolve_file("targets", targets))  # type: ignore[arg-type]
        get_rig(tg.rig)
    except BeambenchError as exc:
        _fail(str(exc))
    stem = (session or targets).stem  # type: ignore[union-attr]
    try:  # before anything is written: the evaluation log, the parameter set and the protocol are named by it
        name = check_name(name, "--name") if name is not None else check_name(f"{stem}_calibrated", "the output name")
    except ValueError as exc:
        _fail(str(exc))
    out_dir = out or default_out()
    stops.arm()  # a stop during the imports and checks above interrupts here
    log.append(out_dir / f"{name}.evals.jsonl")
    _check_outputs(out_dir, name)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _fail(f"--out {out_dir}: cannot create ({exc.strerror or exc})")
    chosen = _free_unknowns(free, tg.rig)
    fast = SearchSettings.quick(**{**dict(get_rig(tg.rig).quick), "free": chosen})  # the rig's own quick settings
    settings = replace(fast, budget_s=min(budget_s, fast.budget_s)) if quick else SearchSettings(budget_s, free=chosen)
    console = stderr_console()
    cols = (
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed} runs"),
        TimeElapsedColumn(),
        TextColumn("{task.fields[left]}"),  # the search's time left of its budget (a TimeLeft)
    )
    try:
        with LogProgress(*cols, console=console, transient=False) as progress:
            result = calibrate(
                tg, out_dir, name, workers=workers, scheduler=scheduler, settings=settings, progress=progress
            )
        report = write_report(result, tg, out_dir, name)
    except (BeambenchError, ExecutorError) as exc:
        _fail(str(exc))
    _finish(result, report)


CALIBRATION_OUTPUTS = (  # what a calibration named NAME writes into its folder
    "{}.evals.jsonl",
    "{}_params.yaml",
    "{}.yaml",
    "{}_report.json",
    "{}_report.md",
    "{}_objective.png",
    "{}_maps.png",
    "{}_verify",
)


def _check_outputs(out_dir: Path, name: str) -> None:
    """The folder takes files and none of the calibration's outputs is a link (planted where they go)."""
    from beambench.common.outputs import output_folder_problem

    problem = output_folder_problem(out_dir, tuple(f.format(name) for f in CALIBRATION_OUTPUTS))
    if problem:
        _fail(f"--out: {problem}")


def _free_unknowns(free: str | None, rig: str) -> tuple[str, ...] | None:
    """``--free`` as unknown names of ``rig`` (None: the rig's default set); one line and exit 2 if wrong."""
    from beambench.studies.twin_calibration import get_rig

    if free is None:
        return None
    chosen = tuple(n.strip() for n in free.split(",") if n.strip())
    known = {u.name for u in get_rig(rig).unknowns}
    bad = [n for n in chosen if n not in known]
    if not chosen or bad:
        _fail(f"--free {free}: {rig} rig unknowns are {', '.join(sorted(known))}")
    twice = sorted({n for n in chosen if chosen.count(n) > 1})
    if twice:
        _fail(f"--free {free}: {twice[0]} is named twice")
    return chosen


def _finish(result: Any, report: Path) -> None:
    """The summary and one line per target (stderr), the protocol's path (stdout), then the verdict as the last
    line (stderr); exit :data:`EXIT_MISSED` when a target is missed."""
    from beambench.studies.twin_calibration.verdict import all_met, closing_line

    twin = ", ".join(f"{k} {v}" for k, v in result.summary.items() if k != "map" and not isinstance(v, dict))
    typer.echo(
        f"objective J {result.j:.4f} ({result.j_stage}); "
        + ", ".join(f"{k} {v:.4g}" for k, v in result.values.items())
        + (f"; twin {twin}" if twin else "")
        + f"; {result.evaluations} runs ({result.reused} re-used), {result.wall_s:.0f} s; report {report}",
        err=True,
    )
    for v in result.verdicts:
        typer.echo(f"  {v.line()}", err=True)
    typer.echo(str(result.protocol))
    typer.echo(f"beambench: {closing_line(result.verdicts)}", err=True)
    if not all_met(result.verdicts):
        raise typer.Exit(EXIT_MISSED)


def register_sim(sub: typer.Typer) -> None:
    """Add ``beambench calibrate sim`` to the ``calibrate`` sub-app."""
    sub.command("sim", epilog=EPILOG, cls=_SimCommand)(sim)
