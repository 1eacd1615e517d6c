"""The ``beambench`` command line: run protocols, view and analyse sessions, drive and check devices."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from typing import NoReturn

from beambench.common import early_signals

if __name__ == "__main__" or os.path.basename(sys.argv[0]) == "beambench":  # the program (not a test's import)
    early_signals.hold()  # a stop signal during the imports below is taken by the command, not lost in a traceback

# beambench never draws with MuJoCo's OpenGL (its figures are matplotlib's, its live view Rerun's). Left unset,
# importing mujoco imports GLFW, and GLFW's import starts a `python -c` probe of its library version: a process
# start per command, and a probe that outlives a killed parent prints a BrokenPipeError traceback on the run's
# stderr. Set before the commands import mujoco; a user's own MUJOCO_GL wins.
os.environ.setdefault("MUJOCO_GL", "disable")

import typer

from beambench import __version__
from beambench.commands import (
    EXIT_STOPPED,
    HELP_MARKUP,
    STANDALONE,
    analyze,
    bench,
    calibrate,
    devices,
    doctor,
    fit,
    natnet,
    run,
    sweep,
)
from beambench.common.out_of_memory import memory_limited, out_of_memory, out_of_memory_here, preload_blas
from beambench.common.unfinished import left_unfinished


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
COMMAND_MODULES = (run, natnet, devices, doctor, calibrate, analyze, bench, fit, sweep)

for _module in COMMAND_MODULES:
    _module.register(app)


def main() -> None:
    """The ``beambench`` entry point: usage errors come out as one line like every other error (exit 2)."""
    STANDALONE["process"] = True
    try:
        try:
            # the commands that take stop signals themselves take the ones that came while importing; for the
            # others they are raised again now (inside: such a Ctrl-C ends like any other, below)
            early_signals.release(sys.argv[1:2] == ["run"] or sys.argv[1:3] == ["calibrate", "sim"])
            _main_inner()
        except KeyboardInterrupt:  # Ctrl-C where no command took it (imports, a prompt): one line, never exit 130
            _exit_code_decided()
            with contextlib.suppress(OSError):
                typer.echo("beambench: aborted", err=True)
            sys.exit(EXIT_STOPPED)
    except SystemExit as exc:
        try:  # noqa: SIM105  (plain try: out of memory even for the call, the exit goes on)
            _exit_code_decided()
        except BaseException:
            pass
        code = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1
        # something a library's exit handler would hang or crash on (a session file HDF5 could not close, a Rerun
        # recording whose file sink never finished: a full disk); a failed command under a memory limit: the
        # interpreter's shutdown (threads that could not start, extension exit handlers) needs memory too and has
        # crashed there (SIGSEGV after the one line). Both end at once.
        if left_unfinished() or (code != 0 and _limited()):
            with contextlib.suppress(Exception):
                sys.stdout.flush()
                sys.stderr.flush()
            os._exit(code)
        raise
    except BaseException as exc:  # out of memory even for the one line (the handlers below allocate): a line built
        # at start, and no interpreter shutdown (it would need memory too); under a memory limit an extension that
        # fails to allocate may not even set its error (SystemError: "error return without exception set")
        if not isinstance(exc, MemoryError):  # checked first: the check below allocates
            if isinstance(exc, KeyboardInterrupt):  # a second Ctrl-C while the first one's line was said
                _exit_code_decided()
                sys.exit(EXIT_STOPPED)
            try:
                oom = out_of_memory_here(exc) is not None
            except MemoryError:
                oom = True
            if not oom:
                raise
        _out_of_memory_exit(None)


def _limited() -> bool:
    """:func:`memory_limited`, False if even that cannot be asked."""
    try:
        return memory_limited()
    except BaseException:
        return False


def _exit_code_decided() -> None:
    """The command has decided how the process ends; from here a stop signal cannot change that. SIGINT is
    ignored (a late Ctrl-C would raise in the middle of the exit), and CPython forgets any KeyboardInterrupt the
    command caught: one that left code run from a string — ``exec``/``eval``, as dataclasses and namedtuples make
    their methods, or an extension's init through ``PyRun_String`` (MuJoCo's) — is remembered as unhandled even
    when caught, and ``python -m beambench`` would end by killing itself with SIGINT (exit -2, or 130 in a shell)
    instead of with its code. Running a string resets that memory (CPython resets it at the start of every run).
    Nothing here imports or may raise (under a memory limit an import can fail)."""
    # plain tries (no context manager): out of memory or interrupted before the ignore, the exit goes on
    try:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)
    except BaseException:
        pass
    try:  # noqa: SIM105
        exec("")  # an empty string: resets that memory, nothing else
    except BaseException:
        pass


_OUT_OF_MEMORY = b"beambench: error: out of memory; give the command more memory\n"  # built before it is needed


def _out_of_memory_exit(reason: str | None) -> NoReturn:
    """One line (naming ``reason`` if the memory for it is there), exit 1 at once: with no memory left the
    interpreter's own shutdown fails with lines of its own and exit 120. A run that had armed the motor idled it
    on its way out; its session file is closed."""
    try:
        line = f"beambench: error: out of memory ({reason}); give the command more memory\n".encode() if reason else b""
    except MemoryError:
        line = b""
    for flush in (sys.stdout.flush, sys.stderr.flush):  # plain try: a context manager is an allocation
        try:  # noqa: SIM105
            flush()
        except BaseException:
            pass
    try:  # noqa: SIM105
        os.write(2, line or _OUT_OF_MEMORY)
    except BaseException:
        pass
    os._exit(1)


def _main_inner() -> None:
    blas = preload_blas()  # under a memory limit: OpenBLAS failing to start its threads is not a Ctrl-C
    if blas is not None:
        _out_of_memory_exit(blas)
    try:
        code = app(standalone_mode=False, prog_name="beambench")
    except typer.Abort:  # click's answer to KeyboardInterrupt or EOFError outside a run (a prompt, the imports)
        with contextlib.suppress(OSError):
            typer.echo("beambench: aborted", err=True)
        sys.exit(EXIT_STOPPED)
    except Exception as exc:
        # click's exceptions (typer vendors its own click, so match by shape, not by class)
        if not (hasattr(exc, "format_message") and hasattr(exc, "exit_code")):
            reason = out_of_memory(exc)
            if reason is None:
                raise
            _out_of_memory_exit(reason)
        if early_signals.take():  # held for a command that takes stop signals itself but never started (bad flags)
            with contextlib.suppress(OSError):
                typer.echo("beambench: aborted", err=True)
            sys.exit(EXIT_STOPPED)
        ctx = getattr(exc, "ctx", None)
        if type(exc).__name__ == "NoArgsIsHelpError" and ctx is not None:  # bare ``beambench`` or a group
            typer.echo(ctx.get_help())
            sys.exit(0)
        hint = f" (see '{ctx.command_path} --help')" if ctx is not None else ""
        typer.echo(f"beambench: error: {exc.format_message()}{hint}", err=True)
        sys.exit(exc.exit_code)
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    main()
