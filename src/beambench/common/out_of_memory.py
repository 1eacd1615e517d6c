"""One answer to "did the process run out of memory?", shared by the runner and the command line.

Under a memory limit the failure takes several shapes: a ``MemoryError``, MuJoCo's "Could not allocate memory",
an extension module's import that cannot map its segment, or CPython refusing a thread ("can't start new thread").
Each is a resource running out, not a bug, and gets one line instead of a traceback.
"""

from __future__ import annotations

__all__ = ["out_of_memory"]

_NO_MEMORY = ("could not allocate memory", "cannot allocate memory", "failed to map segment", "can't start new thread")
_CHAIN = 8  # how far down __cause__/__context__ to look


def out_of_memory(exc: BaseException) -> str | None:
    """What ran out, if ``exc`` (or an exception it came from) is the process running out of memory; else None."""
    seen: BaseException | None = exc
    for _ in range(_CHAIN):
        if seen is None:
            return None
        if isinstance(seen, MemoryError):
            return "MemoryError"
        text = str(seen).strip().splitlines()[0] if str(seen).strip() else ""
        if any(m in text.lower() for m in _NO_MEMORY):
            return f"{type(seen).__name__}: {text[:160]}"
        seen = seen.__cause__ or seen.__context__
    return None
