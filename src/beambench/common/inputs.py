"""Every file a user hands to beambench is checked for its kind and size before a byte of it is read.

A directory, a FIFO (which would block the read), a device (``/dev/zero`` never ends) or a file far larger than
its kind ever is (a 2 GB ``--targets`` was once read whole: 4.3 GB of memory, 10-19 s, before a YAML error) is
refused with one line naming the file and what is wrong: :class:`InputFileError`, a
:class:`~beambench.common.errors.BeambenchError` (the commands turn it into ``beambench: error: …``, exit 2).
"""

from __future__ import annotations

import os
import stat
from collections.abc import Callable
from pathlib import Path

from beambench.common.errors import BeambenchError

__all__ = ["InputFileError", "check_input_file", "read_input_bytes"]


class InputFileError(BeambenchError, ValueError):
    """An input file that is not what it claims (missing, not a regular file, too large); one line."""


def check_input_file(
    path: str | Path, what: str, max_bytes: int | None, error: Callable[[str], Exception] = InputFileError
) -> int:
    """Raise ``error`` (one line) unless ``path`` is a regular file of at most ``max_bytes`` (None: any size);
    returns its size. ``what`` names the input in the message (``targets file``, ``session``…)."""
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise error(f"{p}: no such {what}") from None
    except OSError as exc:
        raise error(f"{p}: cannot read the {what} ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"{p}: a folder, not a {what}")
    if not stat.S_ISREG(st.st_mode):
        kind = "a FIFO" if stat.S_ISFIFO(st.st_mode) else "a device" if stat.S_ISCHR(st.st_mode) else "not a file"
        raise error(f"{p}: {kind}, not a regular file (the {what} must be a file)")
    if max_bytes is not None and st.st_size > max_bytes:
        raise error(f"{p}: {_size(st.st_size)}, larger than any {what} ({_size(max_bytes)} at most)")
    return int(st.st_size)


def read_input_bytes(
    path: str | Path, what: str, max_bytes: int, error: Callable[[str], Exception] = InputFileError
) -> bytes:
    """The bytes of a checked input file, never more than ``max_bytes`` read (a file that grows meanwhile too)."""
    check_input_file(path, what, max_bytes, error)
    try:
        with open(path, "rb") as fh:
            raw = fh.read(max_bytes + 1)
    except OSError as exc:
        raise error(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    if len(raw) > max_bytes:
        raise error(f"{path}: larger than any {what} ({_size(max_bytes)} at most)")
    return raw


def _size(n: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"
