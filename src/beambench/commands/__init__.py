"""One module per CLI command; each has ``register(app)``. The chores every command shares live here."""

from __future__ import annotations

from typing import TYPE_CHECKING, NoReturn

import typer

if TYPE_CHECKING:
    from rich.console import Console

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
    from beambench.common.console import stderr_console

    return stderr_console()
