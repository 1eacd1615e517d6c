"""The ``beambench`` command line: run protocols, view and analyse sessions, drive and check devices."""

from __future__ import annotations

import sys

import typer

from beambench import __version__
from beambench.commands import HELP_MARKUP, analyze, bench, calibrate, devices, fit, natnet, run, sweep


def _version(value: bool) -> None:
    if value:
        typer.echo(f"beambench {__version__}")
        raise typer.Exit()


app = typer.Typer(
    name="beambench",
    help="Test-bench control and data acquisition for soft twisted-beam robots. Runs on a MuJoCo simulation by "
    "default; add --backend hardware for the lab rig.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=HELP_MARKUP,
)


@app.callback()
def _main(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Test-bench control and data acquisition for soft twisted-beam robots. Runs on a MuJoCo simulation by
    default; add --backend hardware for the lab rig."""


# One module per command (or command group), each with ``register(app)``, in the order of the help; imported by
# name in the code (never from a string), so the import contracts see every edge.
COMMAND_MODULES = (run, natnet, devices, calibrate, analyze, bench, fit, sweep)

for _module in COMMAND_MODULES:
    _module.register(app)


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
