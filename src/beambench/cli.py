"""The ``beambench`` command line: run protocols, view and analyse sessions, drive and check devices."""

from __future__ import annotations

import importlib
import os
import sys
from pathlib import Path
from typing import NoReturn

import typer

from beambench.acquisition.config import ConfigError

app = typer.Typer(
    name="beambench",
    help="Test-bench control and data acquisition for soft twisted-beam robots. "
    "Runs on a MuJoCo simulation by default; add --backend hardware for the lab rig.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

# Command modules contributed by each area; each has ``register(app)``. Imported lazily-cheap modules only.
COMMAND_MODULES = ("natnet", "devices", "calibrate", "analyze", "bench", "fit", "sweep")


def fail(message: str, code: int = 2) -> NoReturn:
    """One line on stderr, no traceback, non-zero exit."""
    typer.echo(f"beambench: error: {message}", err=True)
    raise typer.Exit(code)


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or sys.platform in ("darwin", "win32")


@app.command()
def run(
    protocol_file: Path = typer.Argument(
        ..., metavar="PROTOCOL", help="Protocol YAML, e.g. protocols/contact_sweep.yaml."
    ),
    backend: str = typer.Option(
        None, "--backend", "-b", help="sim | emulated | hardware (default: the protocol's, else sim)."
    ),
    out: Path = typer.Option(Path("data"), "--out", "-o", help="Folder for the session files."),
    name: str = typer.Option(None, "--name", "-n", help="Session name (default: the protocol's output.name template)."),
    rerun: str = typer.Option(
        None, "--rerun", help="spawn | connect | save | off (default: spawn with a display, else save)."
    ),
    realtime: bool = typer.Option(False, "--realtime", help="Pace the simulation to the wall clock."),
    dry_run: bool = typer.Option(False, "--dry-run", help="Print the steps, duration and limits; move nothing."),
    rig_file: Path = typer.Option(
        None, "--rig", help="Rig wiring YAML for emulated/hardware (default calibration/rig.yaml)."
    ),
    can_log: Path = typer.Option(
        None, "--can-log", help="Record all CAN traffic to this .asc or .blf file (ODrive over CAN)."
    ),
) -> None:
    """Run a frequency sweep: step the motor, record mocap, load cells and motor telemetry to an HDF5 session.

    Prints the path of the session file (<out>/<name>.h5); with --rerun save also writes <out>/<name>.rrd.
    Limits are checked before anything moves. Ctrl-C idles the motor and closes the file cleanly.
    """
    from beambench.acquisition.config import load_protocol
    from beambench.acquisition.plan import session_path, summary
    from beambench.session.checks import check_protocol

    try:
        protocol, text = load_protocol(protocol_file)
        chosen = backend or protocol.backend
        if chosen not in ("sim", "emulated", "hardware"):
            raise ConfigError("<cli>", "--backend", chosen, "must be sim, emulated or hardware")
        check_protocol(protocol, str(protocol_file), chosen, can_log)  # every field, dry run included
        mode = rerun or ("spawn" if has_display() else "save")
        if mode not in ("spawn", "connect", "save", "off"):
            raise ConfigError("<cli>", "--rerun", mode, "must be spawn, connect, save or off")
        if dry_run:
            _print_dry_run(summary(protocol, chosen))
            return
        path = session_path(protocol, chosen, out, name)
    except ConfigError as exc:
        fail(str(exc))
    from beambench.session.run import run_session

    try:
        result = run_session(
            protocol, text, chosen, path, rerun_mode=mode, realtime=realtime, rig_file=rig_file, can_log=can_log
        )
    except ConfigError as exc:
        fail(str(exc))
    typer.echo(str(path))
    if mode == "save":
        typer.echo(str(path.with_suffix(".rrd")))
    if result.status != "completed":
        typer.echo(f"beambench: run {result.status}: {result.message} (session saved)", err=True)
        raise typer.Exit(130 if result.status == "interrupted" else 1)


def _print_dry_run(s: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"Dry run: {s['protocol']} on the {s['rig']} rig ({s['backend']} backend) — nothing moves")
    t.add_column("step", justify="right")
    t.add_column("frequency (Hz)", justify="right")
    t.add_column("settle + record (s)", justify="right")
    for i, f in enumerate(s["frequencies_hz"]):
        t.add_row(str(i), f"{f:g}", f"{s['settle_s']:g} + {s['record_s']:g}")
    con = Console()
    con.print(t)
    lim = s["limits"]
    con.print(
        f"steps: {s['steps']}   total duration: {s['total_duration_s']:g} s   max frequency: {s['max_frequency_hz']:g} Hz"
        f"   amplitude: {s['amplitude_mm']:g} mm\nlimits: max_frequency_hz={lim['max_frequency_hz']:g}"
        f"  max_current_a={lim['max_current_a']:g}  max_amplitude_mm={lim['max_amplitude_mm']:g}"
    )


@app.command()
def view(
    session: Path = typer.Argument(..., metavar="SESSION", help="A session file (.h5) written by `beambench run`."),
    rerun: str = typer.Option(
        None, "--rerun", help="spawn | connect | save (default: spawn with a display, else save)."
    ),
    out: Path = typer.Option(None, "--out", help="With --rerun save: the .rrd to write (default: beside the session)."),
) -> None:
    """Replay a recorded session into the Rerun viewer (or into an .rrd file)."""
    mode = rerun or ("spawn" if has_display() else "save")
    if mode not in ("spawn", "connect", "save"):
        fail(f"--rerun = {mode!r}: must be spawn, connect or save")
    if not session.is_file():
        fail(f"{session}: no such session file")
    from beambench.session.replay import replay_session

    try:
        rrd = replay_session(session, mode, out)
    except OSError as exc:
        fail(f"{session}: cannot read session ({exc})")
    if rrd is not None:
        typer.echo(str(rrd))


def _register_command_modules() -> None:
    for mod_name in COMMAND_MODULES:
        importlib.import_module(f"beambench.commands.{mod_name}").register(app)


_register_command_modules()


def main() -> None:
    """The ``beambench`` entry point: usage errors come out as one line like every other error (exit 2)."""
    try:
        code = app(standalone_mode=False, prog_name="beambench")
    except Exception as exc:
        # click's exceptions (typer vendors its own click, so match by shape, not by class)
        if not (hasattr(exc, "format_message") and hasattr(exc, "exit_code")):
            raise
        ctx = getattr(exc, "ctx", None)
        if type(exc).__name__ == "NoArgsIsHelpError" and ctx is not None:  # bare ``beambench`` or a group
            typer.echo(ctx.get_help())
            sys.exit(0)
        hint = f" (see '{ctx.command_path} --help')" if ctx is not None else ""
        typer.echo(f"beambench: error: {exc.format_message()}{hint}", err=True)
        sys.exit(exc.exit_code)
    except typer.Abort:
        typer.echo("beambench: aborted", err=True)
        sys.exit(130)
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    main()
