"""The console for progress and notes on standard error (stdout carries only a command's result), and the one
progress display every long command uses (:class:`LogProgress`)."""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from rich.progress import Progress

if TYPE_CHECKING:
    from rich.console import Console
    from rich.progress import Task

LOG_WIDTH = 200  # columns when stderr is a file or a pipe: rich's default of 80 cut lines short ("2 wor…")
PROGRESS_INTERVAL_S = 10.0  # a plain progress line at least this often when stderr is not a terminal
PROGRESS_ENV = "BEAMBENCH_PROGRESS_S"  # seconds between plain progress lines (default PROGRESS_INTERVAL_S)


def stderr_console() -> Console:
    """A rich console on stderr: the terminal's width on a terminal; on a file or a pipe ``$COLUMNS`` if set, else
    :data:`LOG_WIDTH` columns, so a log keeps whole lines."""
    from rich.console import Console

    if sys.stderr.isatty() or os.environ.get("COLUMNS"):
        return Console(stderr=True)
    return Console(stderr=True, width=LOG_WIDTH)


def progress_interval_s() -> float:
    """Seconds between plain progress lines: ``$BEAMBENCH_PROGRESS_S`` if a positive number, else 10."""
    raw = os.environ.get(PROGRESS_ENV, "")
    try:
        value = float(raw)
    except ValueError:
        return PROGRESS_INTERVAL_S
    return value if value > 0 else PROGRESS_INTERVAL_S


class LogProgress(Progress):
    """A rich :class:`~rich.progress.Progress` (same arguments) that also works where nobody watches a terminal.

    On a terminal (or in Jupyter) it is rich's live bar. On a log file, a pipe or CI, where rich would print
    nothing until the end, it prints one plain timestamped line per task every :func:`progress_interval_s`
    (``12:03:40 step 3/8  26 Hz: 14/40 (35 %), 0:00:12 elapsed``), and a last line per task when it stops
    (none for a ``transient`` display)."""

    def __init__(self, *columns: Any, **kwargs: Any) -> None:
        from rich.console import Console

        console = kwargs.get("console") or Console(stderr=True)
        kwargs["console"] = console
        shown = not kwargs.get("disable", False)
        self.plain = shown and not console.is_terminal and not console.is_jupyter
        if self.plain:
            kwargs["disable"] = True  # no live display: the lines below instead
        self._transient_plain = bool(kwargs.get("transient", False))
        self._interval_s = progress_interval_s()
        self._halt = threading.Event()
        self._ticker: threading.Thread | None = None
        super().__init__(*columns, **kwargs)

    def start(self) -> None:
        super().start()
        if self.plain and self._ticker is None:
            self._halt.clear()
            self._ticker = threading.Thread(target=self._tick, name="beambench-progress", daemon=True)
            self._ticker.start()

    def stop(self) -> None:
        ticker, self._ticker = self._ticker, None
        if ticker is not None:
            self._halt.set()
            ticker.join()
            if not self._transient_plain:
                self._print_lines()
        super().stop()

    def _tick(self) -> None:
        while not self._halt.wait(self._interval_s):
            self._print_lines()

    def _print_lines(self) -> None:
        with self._lock:
            lines = [plain_line(task) for task in self.tasks if task.visible]
        stamp = time.strftime("%H:%M:%S")
        with contextlib.suppress(OSError, ValueError):  # a hung-up terminal or a closed pipe: only the lines end
            out = self.console.file
            out.write("".join(f"{stamp} {line}\n" for line in lines))
            out.flush()


class TimeLeft:
    """A progress field that says, each time it is shown, the time left of a budget (``str()`` reads the
    clock): "1:20 left of the 150 s budget", then "150 s budget spent: finishing" once it is over."""

    def __init__(self, budget_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.budget_s, self.clock = budget_s, clock
        self.start = clock()

    def __str__(self) -> str:
        left = round(self.budget_s - (self.clock() - self.start))
        if left <= 0:
            return f"{self.budget_s:g} s budget spent: finishing"
        return f"{left // 60}:{left % 60:02d} left of the {self.budget_s:g} s budget"


def plain_line(task: Task) -> str:
    """One task as plain text: description, done/total (percent), extra fields, elapsed time."""
    from rich.errors import MarkupError
    from rich.text import Text

    try:
        what = Text.from_markup(task.description).plain
    except MarkupError:
        what = task.description
    done = f"{task.completed:g}" + (f"/{task.total:g} ({task.percentage:.0f} %)" if task.total else "")
    extra = "".join(f", {v}" for v in task.fields.values() if str(v))
    elapsed = int(task.elapsed or 0.0)
    return f"{what}: {done}{extra}, {elapsed // 3600}:{elapsed // 60 % 60:02d}:{elapsed % 60:02d} elapsed"
