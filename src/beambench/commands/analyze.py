"""``beambench analyze SESSION.h5`` and ``beambench compare A.h5 B.h5``: per-step results and a report folder."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from beambench.commands import chatter, fail

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import AnalysisOptions, SessionAnalysis


def _frequencies(text: str | None) -> list[float] | None:
    if not text:
        return None
    try:
        vals = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        fail(f"--force-at {text!r}: expected frequencies in Hz separated by commas, e.g. 26,40")
    if not vals or any(not (math.isfinite(v) and v > 0) for v in vals):
        fail(f"--force-at {text!r}: expected positive, finite frequencies in Hz")
    return vals


FIGURES_HELP = (
    "Figures to draw: all (the session's rig's), none (steps.csv, index.html and the stored results only: fast, "
    "for batches), or names separated by commas, e.g. trajectories,forces."
)


def _figure_names(text: str) -> list[str] | None:
    """``--figures``: None for all, [] for none, else the named figure keys (each a registered figure)."""
    from beambench.analysis.figures import FIGURES

    words = [w.strip() for w in text.split(",") if w.strip()]
    if words == ["all"]:
        return None
    if words == ["none"]:
        return []
    known = FIGURES.keys()
    unknown = [w for w in words if w not in known]
    if not words or unknown:
        fail(
            f"--figures {text!r}: expected all, none or figure names separated by commas"
            + (f"; not a figure: {', '.join(unknown)}" if unknown else "")
            + f" (figures: {', '.join(known)})"
        )
    return words


def _check_figures(only: list[str] | None, analyses: list[SessionAnalysis]) -> None:
    """Every figure named in ``--figures`` is one a report on these sessions draws."""
    from beambench.analysis.report import figures_of

    drawn = figures_of(analyses)
    other = [k for k in only or [] if k not in drawn]
    if other:
        rigs = " and ".join(sorted({a.rig for a in analyses}))
        fail(f"--figures: {', '.join(other)} not drawn for {rigs} sessions (theirs: {', '.join(drawn)})")


def _options(up: str | None, forward: str | None, drift_correct: bool = False) -> AnalysisOptions:
    from beambench.analysis.session_analysis import AnalysisOptions
    from beambench.analysis.trajectory import axis_vector

    for name, value in (("--up", up), ("--forward", forward)):
        if value is not None:
            try:
                axis_vector(value)
            except ValueError:
                fail(f"{name} {value!r}: expected x, y or z with an optional sign, e.g. z or -y")
    return AnalysisOptions(up=up, forward=forward, drift_correct=drift_correct)


def _must_exist(path: Path) -> None:
    """A missing session file is one line and exit code 2."""
    if not path.is_file():
        fail(f"{path}: no such file")


def _read(path: Path) -> Any:
    """Read one session; a missing, foreign or empty file becomes one line and exit code 2."""
    from beambench.sinks.session_file.reader import SessionFileError, read_session

    _must_exist(path)
    try:
        session = read_session(path)
    except SessionFileError as exc:  # already one line naming the file
        fail(str(exc))
    except (OSError, KeyError) as exc:
        fail(f"{path}: not a beambench session file ({exc})")
    if len(session.steps) == 0:
        fail(f"{path}: the session has no steps to analyse")
    return session


def _same_rig(a: Path, b: Path, sessions: list[Any]) -> None:
    """Refuse to overlay sessions of different rigs (their figures measure different things): exit 2."""
    from beambench.analysis.session_analysis import session_rig

    rigs = [session_rig(dict(s.general)) for s in sessions]
    if rigs[0] != rigs[1]:
        fail(
            f"compare: {a.name} is a {rigs[0]} session and {b.name} a {rigs[1]} session: the rigs differ, "
            "so their figures cannot be overlaid (compare two sessions of one rig)"
        )


def _load(path: Path, options: AnalysisOptions, progress, write: bool, session: Any = None) -> SessionAnalysis:
    """Read (unless given) and analyse one session, with a progress task; errors become one line and exit
    code 2."""
    from beambench.analysis.session_analysis import analyze_session, write_results

    session = session if session is not None else _read(path)
    task = progress.add_task(f"analysing {path.name}", total=len(session.steps))
    try:
        analysis = analyze_session(session, options, lambda k, n: progress.update(task, completed=k))
    except (ValueError, KeyError, IndexError) as exc:  # a malformed session: say what, no traceback
        fail(f"{path}: cannot analyse this session ({type(exc).__name__}: {exc})")
    if write:
        try:
            write_results(analysis)
        except OSError as exc:  # e.g. the file is read-only or still open for writing by a live run
            progress.console.print(f"[yellow]warning: results not written into {path.name}: {exc}")
    return analysis


def _check_outputs(folder: Path, sessions: list[Path], write: bool) -> None:
    """The sessions exist, then every place analyze writes, checked before it writes anything: the report folder,
    and (``write``) each session it stores results in (``/processing``). One line, exit 2."""
    from beambench.common.outputs import output_folder_problem, unwritable_file

    for path in sessions:  # a missing input is the first thing to say, before where the output would go
        _must_exist(path)
    problem = output_folder_problem(folder)  # a link there (planted at the default name) is a taken name
    if problem:
        fail(f"{problem}: the report folder (give another with --out)")
    for path in sessions if write else []:
        problem = unwritable_file(path)
        if problem:
            fail(f"{problem}: the results go into the session (--no-write analyses without storing them)")


def _report(
    analyses: list[SessionAnalysis], out: Path, force_at: list[float] | None, progress, only: list[str] | None
) -> Path:
    from beambench.analysis.report import figures_of, make_report

    _check_figures(only, analyses)
    task = progress.add_task("figures", total=len(figures_of(analyses, only)))
    try:
        return make_report(
            analyses,
            out,
            force_at,
            lambda key: progress.update(task, advance=1, description=f"figure: {key}"),
            only=only,
        )
    except OSError as exc:  # the folder changed under us (checked first): still one line
        fail(f"{out}: cannot write the report ({exc.strerror or exc})")


def _progress(quiet: bool):
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        TextColumn,
        TimeElapsedColumn,
    )

    from beambench.common.console import LogProgress

    return LogProgress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=chatter(),
        disable=quiet,
        transient=True,
    )


def register(app: typer.Typer) -> None:
    """Add ``analyze`` and ``compare`` to the beambench app."""

    @app.command()
    def analyze(
        session: Path = typer.Argument(..., metavar="SESSION.h5", help="A session file written by beambench run."),
        out: Path | None = typer.Option(
            None, "--out", "-o", help="Report folder (default: <session stem>_report/ beside the session)."
        ),
        force_at: str | None = typer.Option(
            None,
            "--force-at",
            help="Frequencies (Hz) for the force-trace figure, e.g. 26,40 (default: one per contact regime).",
        ),
        up: str | None = typer.Option(
            None, "--up", help="World axis pointing up, e.g. z or -y (default: from the session or the rig geometry)."
        ),
        forward: str | None = typer.Option(
            None, "--forward", help="Walker: world axis of forward travel (default: from the session, else x)."
        ),
        no_write: bool = typer.Option(
            False, "--no-write", help="Do not store the results in the session's /processing group."
        ),
        drift_correct: bool = typer.Option(
            False,
            "--drift-correct",
            help="Add <metric>_drift_corrected columns: each step less the reference steps' drift, linearly "
            "interpolated between the references that bracket it (needs a protocol with reference:).",
        ),
        figures: str = typer.Option(
            "all",
            "--figures",
            help=FIGURES_HELP,
        ),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    ) -> None:
        """Analyse every step of a session and write a report folder.

        Per step, on its record window: measured drive frequency and amplitude;
        tip and foot paths in the stage frame, their ellipses and sense of travel;
        contacts from the calibrated normal force (frequency, per cycle, regime);
        direction of motion at touchdown and the tangential force; walker speed.

        Writes PNG figures, steps.csv and index.html, stores the results in the
        session's /processing group and prints the path of index.html.
        """
        freqs = _frequencies(force_at)
        only = _figure_names(figures)
        opts = _options(up, forward, drift_correct)
        folder = out or session.with_name(f"{session.stem}_report")
        _check_outputs(folder, [session], write=not no_write)
        with _progress(quiet) as progress:
            a = _load(session, opts, progress, not no_write)
            index = _report([a], folder, freqs, progress, only)
        typer.echo(str(index))

    @app.command()
    def compare(
        a: Path = typer.Argument(..., metavar="A.h5", help="First session (e.g. sim)."),
        b: Path = typer.Argument(..., metavar="B.h5", help="Second session (e.g. rig)."),
        out: Path | None = typer.Option(
            None, "--out", "-o", help="Report folder (default: <A stem>_vs_<B stem>_report/ beside A)."
        ),
        force_at: str | None = typer.Option(
            None, "--force-at", help="Frequencies (Hz) for the force-trace figure, e.g. 26,40."
        ),
        up: str | None = typer.Option(
            None, "--up", help="World axis pointing up for both sessions (default: from each session)."
        ),
        forward: str | None = typer.Option(None, "--forward", help="Walker: world axis of forward travel."),
        no_write: bool = typer.Option(
            False, "--no-write", help="Do not store results in the sessions' /processing groups."
        ),
        figures: str = typer.Option(
            "all",
            "--figures",
            help=FIGURES_HELP,
        ),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    ) -> None:
        """Overlay two sessions (sim vs rig, two models, two beams) on the same report figures.

        Writes the figures of analyze with both sessions on every plot, a
        steps.csv with a session column and index.html with both provenances;
        prints the path of index.html.
        """
        freqs = _frequencies(force_at)
        only = _figure_names(figures)
        opts = _options(up, forward)
        folder = out or a.with_name(f"{a.stem}_vs_{b.stem}_report")
        _check_outputs(folder, [a, b], write=not no_write)
        sessions = [_read(p) for p in (a, b)]
        _same_rig(a, b, sessions)
        with _progress(quiet) as progress:
            analyses = [_load(p, opts, progress, not no_write, s) for p, s in zip((a, b), sessions)]
            if analyses[0].label == analyses[1].label:  # same file name in two folders: say which is which
                for x in analyses:
                    x.name = f"{x.path.parent.name}/{x.path.stem}" if x.path else x.label
            index = _report(analyses, folder, freqs, progress, only)
        typer.echo(str(index))
