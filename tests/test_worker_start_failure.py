"""A pool worker forked while its pool stops cannot receive its start-up state (the pool's semaphores are gone):
the fork server's excepthook ends it without a traceback; every other error still prints one."""

from __future__ import annotations

import sys

import pytest

from beambench.studies.worker_env import quiet_start_failure

SPAWN = "/usr/lib/python3.11/multiprocessing/spawn.py"


def _raised_in(filename: str, name: str, exc: BaseException) -> tuple[type[BaseException], BaseException, object]:
    """``exc`` raised inside a function called ``name`` compiled from ``filename`` (as a traceback shows it)."""
    scope: dict = {}
    exec(compile(f"def {name}(e):\n    raise e\n", filename, "exec"), scope)
    try:
        scope[name](exc)
    except BaseException as caught:
        return type(caught), caught, caught.__traceback__
    raise AssertionError("not raised")


@pytest.mark.parametrize("exc", [FileNotFoundError(2, "No such file or directory"), EOFError("Ran out of input")])
def test_a_worker_that_cannot_receive_its_start_up_state_ends_quietly(exc, capsys):
    quiet_start_failure(*_raised_in(SPAWN, "_main", exc))
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize(
    ("filename", "name", "exc"),
    [
        (SPAWN, "_main", ValueError("a bug in the task")),  # not a missing resource
        ("/src/beambench/studies/evaluate.py", "_main", FileNotFoundError(2, "missing")),  # not the start-up
        (SPAWN, "prepare", FileNotFoundError(2, "missing")),
    ],
)
def test_any_other_error_still_prints_its_traceback(filename, name, exc, capsys):
    quiet_start_failure(*_raised_in(filename, name, exc))
    err = capsys.readouterr().err
    assert "Traceback" in err and type(exc).__name__ in err


def test_the_fork_server_module_installs_it():
    assert sys.modules["beambench.studies.worker_env"].quiet_start_failure is quiet_start_failure
    assert sys.excepthook is quiet_start_failure
