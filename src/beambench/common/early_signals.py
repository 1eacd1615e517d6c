"""Stop signals that arrive while the command line is still importing, before a command has taken them.

Importing the commands takes a second or more; a Ctrl-C or a SIGTERM then would end the process with a
``KeyboardInterrupt`` traceback (exit 130) or silently. :func:`hold` (first thing the CLI module does) records them
instead; :func:`release` (when the command line starts) puts the dispositions back and hands the recorded ones on:
a command that takes stop signals itself (``run``, ``calibrate sim``) takes them with :func:`take`, for the others
they are raised again as if they had just come.
"""

from __future__ import annotations

import signal
import threading
from typing import Any

__all__ = ["hold", "release", "take"]

HELD = ("SIGINT", "SIGTERM", "SIGQUIT")  # the ones every command takes or dies of (SIGHUP and the rest: as before)
_pending: list[int] = []
_previous: dict[int, Any] = {}


def hold() -> None:
    """Record :data:`HELD` signals instead of acting on them (main thread only; idempotent)."""
    if _previous or threading.current_thread() is not threading.main_thread():
        return
    for name in HELD:
        signum = int(getattr(signal, name))
        _previous[signum] = signal.signal(signum, lambda s, frame: _pending.append(s))


def release(taken_by_command: bool) -> None:
    """For a command that takes stop signals itself (``taken_by_command``): nothing changes — the signals stay
    recorded until the command installs its own handlers and :func:`take` s what came (so none falls between the
    two, where a Ctrl-C would end it silently with exit 130). For the others: the dispositions are put back and
    what was recorded is raised again now (a Ctrl-C then ends the command as it would have)."""
    if taken_by_command:
        return
    for signum, previous in _previous.items():
        signal.signal(signum, previous if previous is not None else signal.SIG_DFL)
    _previous.clear()
    for signum in take():
        signal.raise_signal(signum)


def take() -> list[int]:
    """The stop signals recorded while importing (once: they are forgotten here)."""
    got = list(_pending)
    _pending.clear()
    return got
