"""A name the user gives for something written (a session, a parameter set, a calibration) is one path component.

:func:`check_name` refuses, with one short line, what would write outside the chosen folder or make an awkward file
name: empty, ``.``/``..``, a path separator (so an absolute path too), a control character (newline, ESC, NUL…),
more than :data:`MAX_NAME_BYTES` bytes. Commands call it before anything is created.
"""

from __future__ import annotations

import unicodedata

__all__ = ["MAX_NAME_BYTES", "check_name"]

MAX_NAME_BYTES = 200  # a file name without its suffix; file systems allow 255 bytes in all


def check_name(name: str, what: str) -> str:
    """``name`` if it is one usable path component; else ``ValueError`` whose message starts with ``what``."""
    if not name or name in (".", ".."):
        raise ValueError(f"{what} must be a plain file name")
    bad = next((c for c in name if unicodedata.category(c)[0] == "C"), None)
    if bad is not None:
        raise ValueError(f"{what} contains a control character ({bad!r})")
    if "/" in name or "\\" in name:
        raise ValueError(f"{what} must be a plain file name (no / or \\)")
    if len(name.encode("utf-8", "surrogatepass")) > MAX_NAME_BYTES:
        raise ValueError(f"{what} is longer than {MAX_NAME_BYTES} bytes")
    return name
