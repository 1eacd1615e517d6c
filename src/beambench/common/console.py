"""The console for progress and notes on standard error (stdout carries only a command's result)."""

from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rich.console import Console

LOG_WIDTH = 200  # columns when stderr is a file or a pipe: rich's default of 80 cut lines short ("2 wor…")


def stderr_console() -> Console:
    """A rich console on stderr: the terminal's width on a terminal; on a file or a pipe ``$COLUMNS`` if set, else
    :data:`LOG_WIDTH` columns, so a log keeps whole lines."""
    from rich.console import Console

    if sys.stderr.isatty() or os.environ.get("COLUMNS"):
        return Console(stderr=True)
    return Console(stderr=True, width=LOG_WIDTH)
