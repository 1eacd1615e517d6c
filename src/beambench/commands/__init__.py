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

# Exit codes of every command (docs/commands.md, "Exit codes": a test checks that table against EXIT_CODES). All
# below 128: a shell reads 128 + N as "killed by signal N", which a command stopped through its stop path (motor
# idled, session closed, evaluations kept) is not.
EXIT_OK = 0
EXIT_FAULT = 1  # a device fault or an error during the work (run: session saved, motor idled; doctor: a part missing)
EXIT_USAGE = 2  # bad input: a flag, a file, a field (nothing moved, nothing written)
EXIT_STOPPED = 3  # stopped by a signal (Ctrl-C everywhere; run: also SIGTERM, SIGHUP, SIGQUIT, …): cleanly
EXIT_SINK = 4  # a sink failed (a full disk): motor idled, the session holds what was written before
EXIT_MISSED = 5  # calibrate sim: written, but a target is not met within its tolerance

# The codes each command exits with (0, 2 and 3 are every command's: done, bad input, Ctrl-C; 1 too when memory
# runs out, cli.main): the table of docs/commands.md is checked against this, and each command module's code
# against its commands' rows (tests/test_exit_codes.py).
EVERY = (EXIT_OK, EXIT_FAULT, EXIT_USAGE, EXIT_STOPPED)
EXIT_CODES: dict[str, tuple[int, ...]] = {
    "run": (*EVERY, EXIT_SINK),
    "view": (*EVERY, EXIT_SINK),
    "analyze": EVERY,
    "compare": EVERY,
    "devices": EVERY,
    "doctor": EVERY,
    "calibrate loadcells": EVERY,
    "calibrate sim": (*EVERY, EXIT_MISSED),
    "natnet decode": EVERY,
    "bench models": EVERY,
    "fit": EVERY,
    "sweep": EVERY,
}

# True in the ``beambench`` process itself (cli.main), which exits after the command: signals may then stay
# ignored after a run. False when a command is invoked in-process (tests, notebooks): everything is restored.
STANDALONE = {"process": False}

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
