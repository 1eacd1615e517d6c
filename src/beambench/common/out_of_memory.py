"""One answer to "did the process run out of memory?", shared by the runner and the command line.

Under a memory limit the failure takes several shapes: a ``MemoryError``, MuJoCo's "Could not allocate memory",
an extension module's import that cannot map its segment or whose C++ start-up runs out (pybind11 passes on
``std::bad_alloc`` as the import's error: MuJoCo's), or CPython refusing a thread ("can't start new thread").
Each is a resource running out, not a bug, and gets one line instead of a traceback.
"""

from __future__ import annotations

__all__ = ["memory_limited", "out_of_memory", "out_of_memory_here", "preload_blas"]

_NO_MEMORY = (
    "could not allocate memory",
    "cannot allocate memory",
    "failed to map segment",
    "can't start new thread",
    "std::bad_alloc",
)
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


def out_of_memory_here(exc: BaseException) -> str | None:
    """:func:`out_of_memory`, and under an address-space limit a ``SystemError`` too: an extension that fails to
    allocate there may not set its error at all (numpy's fancy indexing: "error return without exception set")."""
    reason = out_of_memory(exc)
    if reason is None and isinstance(exc, SystemError) and memory_limited():
        return f"SystemError under a memory limit: {str(exc)[:160]}"
    return reason


def memory_limited() -> bool:
    """Does this process run under an address-space limit (``prlimit --as``, ``ulimit -v``)?"""
    import resource

    return resource.getrlimit(resource.RLIMIT_AS)[0] != resource.RLIM_INFINITY


class _BlasFailed(Exception):
    """Raised by the SIGINT handler of :func:`preload_blas`: OpenBLAS signalled that it could not start."""


def _blas_failed(signum: int, frame: object) -> None:
    raise _BlasFailed  # ends the import at once: OpenBLAS carries on without its threads and may hang


def preload_blas() -> str | None:
    """Under an address-space limit (``prlimit --as``, ``ulimit -v``), import numpy now, with SIGINT taken as
    OpenBLAS failing: OpenBLAS, loaded with it, prints its own lines and raises SIGINT at
    its own process when it cannot start its threads, which would end the command as if by Ctrl-C (exit 130).
    Returns what ran out if that happened (or the import ran out of memory), else None. Without a limit it does
    nothing (the command imports them when it needs them). Main thread only."""
    import signal

    if not memory_limited():
        return None
    previous = signal.signal(signal.SIGINT, _blas_failed)
    try:
        import numpy  # noqa: F401  (SciPy's own OpenBLAS is not loaded here: under a tight limit its start spins)
    except _BlasFailed:
        return "OpenBLAS could not start its threads"
    except Exception as exc:  # under the limit an import fails in many shapes (a SystemError, an ImportError)
        reason = out_of_memory(exc)
        if reason is None and not isinstance(exc, ImportError):
            raise
        return reason
    finally:
        signal.signal(signal.SIGINT, previous)
    return None
