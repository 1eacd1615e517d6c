"""One module per CLI command; each has ``register(app)``. The chores every command shares live here."""

from __future__ import annotations

import dataclasses
import functools
import inspect
import typing
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NoReturn, TypeVar

import typer

if TYPE_CHECKING:
    from rich.console import Console

# Help as plain paragraphs, rewrapped to the terminal: flags show no type, sentences do not break mid-line.
HELP_MARKUP = None


A = TypeVar("A")


def command_of(args_type: type[A], run: Callable[[A], None]) -> Callable[..., None]:
    """A typer command whose arguments and options are the fields of the dataclass ``args_type`` (defaults:
    ``typer.Argument(...)`` / ``typer.Option(...)``); it calls ``run(args_type(**given))``, so a command with many
    options receives one value. Help text and name come from ``run``."""
    hints = typing.get_type_hints(args_type)
    params = [
        inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default, annotation=hints[f.name])
        for f in dataclasses.fields(args_type)  # type: ignore[arg-type]
    ]

    @functools.wraps(run)
    def command(**given: Any) -> None:
        run(args_type(**given))

    del command.__wrapped__  # typer reads the signature below, not run's
    command.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    command.__annotations__ = {p.name: p.annotation for p in params} | {"return": None}
    return command


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
