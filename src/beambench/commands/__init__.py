"""One module per CLI command; each has ``register(app)``. The chores every command shares live here."""

from __future__ import annotations

from typing import TYPE_CHECKING, NoReturn

import typer

if TYPE_CHECKING:
    from rich.console import Console

# Exit codes of every command (README, "Exit codes"). All below 128: a shell reads 128 + N as "killed by signal
# N", which a run stopped through its stop path (motor idled, session closed) is not.
EXIT_OK = 0
EXIT_FAULT = 1  # a device fault or an error during the run (session saved)
EXIT_USAGE = 2  # bad input: a flag, a file, a field (nothing moved)
EXIT_STOPPED = 3  # stopped by a signal (SIGINT, SIGTERM, SIGHUP, SIGQUIT, …): motor idled, session saved
EXIT_SINK = 4  # a sink failed (a full disk): motor idled, the session holds what was written before

# True in the ``beambench`` process itself (cli.main), which exits after the command: signals may then stay
# ignored after a run. False when a command is invoked in-process (tests, notebooks): everything is restored.
STANDALONE = {"process": False}

# Help as plain paragraphs, rewrapped to the terminal: flags show no type, sentences do not break mid-line.
HELP_MARKUP = None


def fail(message: str, code: int = 2) -> NoReturn:
    """A user-facing error: one line on stderr, no traceback, exit ``code`` (2 unless told)."""
    typer.echo(f"beambench: error: {message}", err=True)
    raise typer.Exit(code)


def sub_app(help: str) -> typer.Typer:
    """A command group (``beambench natnet …``) with the app's help style."""
    return typer.Typer(help=help, no_args_is_help=True, add_completion=False, rich_markup_mode=HELP_MARKUP)


def chatter() -> Console:
    """The console for progress, tables and notes: stderr, so stdout carries only the command's result."""
    from rich.console import Console

    return Console(stderr=True)
