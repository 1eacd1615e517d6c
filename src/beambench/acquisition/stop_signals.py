"""Stop signals: every signal that would end the process becomes a stop request the run obeys.

Every signal that ends a process by default and can be caught (:data:`STOP_SIGNALS`:
SIGINT, SIGTERM, SIGHUP — a closed terminal or SSH session —, SIGQUIT, SIGUSR1/2, SIGALRM, SIGVTALRM, SIGPROF,
SIGXCPU, SIGIO, SIGPWR, SIGSTKFLT and the real-time signals) only sets a :class:`StopSignal` flag, which the
runner reads before and after every poll (settle, record, pause) and between steps, from any state and on every
backend. SIGINT, SIGTERM and SIGQUIT are always taken (a shell's background job ignores SIGINT and SIGQUIT, as it
does not want the terminal's Ctrl-C; a stop sent to the process is still meant); the others only where their
disposition is still the default (terminate): one ignored on purpose (``nohup`` ignores SIGHUP) or handled by
someone else (a profiler's SIGPROF) is left alone. Not caught: SIGKILL and SIGSTOP (they cannot be), the fault signals (SIGSEGV, SIGBUS, SIGFPE,
SIGILL, SIGABRT, SIGTRAP, SIGSYS: a program error, after which nothing can safely run), SIGPIPE and SIGXFSZ
(Python ignores them: the write fails with an error instead, which stops the run through the sink-failure path).
When the process cannot run its stop path at all (SIGKILL, a crash), the ODrive's own watchdog idles the motor. An exception
raised inside a signal handler lands in whatever code happens to run (a weakref callback, a C callback, a
``finally``) and may be swallowed there; a flag cannot be. Further signals during shutdown are only counted,
so a second Ctrl-C cannot skip the idle.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from beambench.common import early_signals


class StopSignal:
    """A stop request: set by the signal handlers (or by :meth:`request`), read by the runner at every poll."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self.count = 0  # signals received, the first included
        self._event = threading.Event()

    def request(self, signum: int = signal.SIGINT) -> None:
        """Ask the run to stop (only sets attributes: safe in a signal handler)."""
        self.count += 1
        if self.signum is None:
            self.signum = signum
        self._event.set()

    @property
    def requested(self) -> bool:
        return self._event.is_set()

    @property
    def reason(self) -> str:
        if self.signum is None:
            return "stopped"
        name = signal_name(self.signum)
        if self.signum == signal.SIGINT:
            return f"interrupted by user ({name})"
        if self.signum == signal.SIGTERM:
            return f"terminated ({name})"
        if self.signum == getattr(signal, "SIGHUP", None):
            return f"hang-up: the terminal or session closed ({name})"
        return f"stopped by {name}"

    def wait(self, timeout: float) -> bool:
        """Sleep up to ``timeout`` s, waking early on a stop request; True if one came."""
        return self._event.wait(timeout)


def signal_name(signum: int) -> str:
    """``SIGHUP``, ``SIGRTMIN+3`` … for a signal number."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        rtmin = getattr(signal, "SIGRTMIN", None)
        if rtmin is not None and rtmin < signum <= getattr(signal, "SIGRTMAX", rtmin):
            return f"SIGRTMIN+{signum - rtmin}"
        return f"signal {signum}"


# SIGINT and SIGQUIT are the two a shell ignores in its background jobs (no job control): taken anyway, as Ctrl-C
# and Ctrl-backslash are the user's; SIGTERM is every supervisor's stop
ALWAYS_TAKEN = ("SIGINT", "SIGTERM", "SIGQUIT")
IF_DEFAULT = (
    "SIGHUP",
    "SIGUSR1",
    "SIGUSR2",
    "SIGALRM",
    "SIGVTALRM",
    "SIGPROF",
    "SIGXCPU",
    "SIGIO",
    "SIGPWR",
    "SIGSTKFLT",
)


def _stop_signals() -> tuple[tuple[int, ...], tuple[int, ...]]:
    """(signals always taken, signals taken where their disposition is the default) on this platform."""
    always = tuple(int(getattr(signal, n)) for n in ALWAYS_TAKEN)
    named = [int(getattr(signal, n)) for n in IF_DEFAULT if hasattr(signal, n)]
    if hasattr(signal, "SIGRTMIN"):
        named += range(int(signal.SIGRTMIN), int(signal.SIGRTMAX) + 1)
    return always, tuple(dict.fromkeys(s for s in named if s not in always))


ALWAYS_SIGNALS, DEFAULT_SIGNALS = _stop_signals()
STOP_SIGNALS = ALWAYS_SIGNALS + DEFAULT_SIGNALS  # every signal that can stop a run through its stop path


@contextmanager
def stop_on_signals(stop: StopSignal | None = None, *, then_ignore: bool = False) -> Iterator[StopSignal]:
    """While inside, the :data:`STOP_SIGNALS` set ``stop`` instead of ending the process (main thread only;
    elsewhere a no-op). Nested uses keep the outer handlers (they set the same flag). ``then_ignore``: after,
    the signals taken are ignored instead of restored (a command line about to exit: a second Ctrl-C just after
    the first must not kill the process between the run and its last line)."""
    stop = stop or StopSignal()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return

    def handler(signum: int, frame: object) -> None:
        stop.request(signum)

    old: dict[int, Any] = {}
    try:
        for signum in STOP_SIGNALS:
            current = signal.getsignal(signum)
            if signum in DEFAULT_SIGNALS and current is not signal.SIG_DFL:
                continue  # ignored on purpose (nohup), or someone else's (a profiler): left alone
            old[signum] = signal.signal(signum, handler)
        for signum in early_signals.take():  # a stop while the command line was importing
            stop.request(signum)
        yield stop
    finally:
        for signum, previous in old.items():
            signal.signal(signum, signal.SIG_IGN if then_ignore else previous)
