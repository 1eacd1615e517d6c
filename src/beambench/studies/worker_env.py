"""Imported first in the local fork server (:mod:`beambench.studies.executor`), before NumPy or pyarrow: keep the
server single-threaded, so that forking workers from it copies no thread's half-held lock.

- ``OPENBLAS_NUM_THREADS=1`` (and the OpenMP/MKL equivalents): NumPy's and SciPy's BLAS would otherwise start a
  thread pool at import; a pool worker runs one simulation per core and needs no BLAS threads.
- ``JE_ARROW_MALLOC_CONF=background_thread:false``: pyarrow's jemalloc otherwise starts its
  ``jemalloc_bg_thd`` purge thread when the library loads (pandas imports pyarrow).

A user's own setting of any of them wins.

The server's ``sys.excepthook`` (:func:`quiet_start_failure`) keeps a worker forked as its pool stops from printing
a traceback for the pool's resources being gone.
"""

from __future__ import annotations

import os
import sys
from types import TracebackType

for _name, _value in (
    ("OPENBLAS_NUM_THREADS", "1"),
    ("OMP_NUM_THREADS", "1"),
    ("MKL_NUM_THREADS", "1"),
    ("JE_ARROW_MALLOC_CONF", "background_thread:false"),
):
    os.environ.setdefault(_name, _value)


def quiet_start_failure(kind: type[BaseException], value: BaseException, tb: TracebackType | None) -> None:
    """The fork server's ``sys.excepthook`` (its workers inherit it): a worker that cannot even receive its
    start-up state — an ``OSError``/``EOFError`` while ``multiprocessing.spawn._main`` unpickles it, because its
    pool was stopped and its semaphores and pipes are gone while it was being forked — ends without a traceback
    (a pool still in use sees the worker's end as a broken pool and says so); anything else is printed as usual."""
    if issubclass(kind, OSError | EOFError):
        t = tb
        while t is not None:
            code = t.tb_frame.f_code
            if code.co_name == "_main" and code.co_filename.replace("\\", "/").endswith("multiprocessing/spawn.py"):
                return
            t = t.tb_next
    sys.__excepthook__(kind, value, tb)


sys.excepthook = quiet_start_failure
