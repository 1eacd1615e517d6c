"""Imported first in the local fork server (:mod:`beambench.studies.executor`), before NumPy or pyarrow: keep the
server single-threaded, so that forking workers from it copies no thread's half-held lock.

- ``OPENBLAS_NUM_THREADS=1`` (and the OpenMP/MKL equivalents): NumPy's and SciPy's BLAS would otherwise start a
  thread pool at import; a pool worker runs one simulation per core and needs no BLAS threads.
- ``JE_ARROW_MALLOC_CONF=background_thread:false``: pyarrow's jemalloc otherwise starts its
  ``jemalloc_bg_thd`` purge thread when the library loads (pandas imports pyarrow).

A user's own setting of any of them wins.
"""

from __future__ import annotations

import os

for _name, _value in (
    ("OPENBLAS_NUM_THREADS", "1"),
    ("OMP_NUM_THREADS", "1"),
    ("MKL_NUM_THREADS", "1"),
    ("JE_ARROW_MALLOC_CONF", "background_thread:false"),
):
    os.environ.setdefault(_name, _value)
