"""What this process had to leave unfinished, where a library's exit handler would hang or crash on it.

A session file HDF5 could not close (a full disk): HDF5's exit handler retries the close and crashes. A Rerun
recording whose file sink never finished: the SDK's drop at interpreter shutdown waits for that sink for ever.
A process that ran out of memory: a library that failed to allocate may have damaged its heap, and the exit handlers
then abort in glibc.
Whatever leaves such a thing records it here (keeping its objects alive, so no finaliser retries before the
end); the command line then ends the process with :func:`os._exit` after its last line, past every exit handler.
"""

from __future__ import annotations

__all__ = ["leave_unfinished", "left_unfinished"]

_LEFT: list[tuple[str, tuple[object, ...]]] = []


def leave_unfinished(what: str, *keep: object) -> None:
    """Record that ``what`` (e.g. ``session file PATH``) was left unfinished; ``keep``: its library objects, held
    until the process ends (released earlier, they would retry the work that failed)."""
    _LEFT.append((what, keep))


def left_unfinished() -> list[str]:
    """What this process left unfinished (empty if nothing): then only ``os._exit`` ends it cleanly."""
    return [what for what, _ in _LEFT]
