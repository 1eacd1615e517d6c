"""The one executor seam for parallel work (sweeps, batched fits): a ``concurrent.futures.Executor``.

- **Local (default)**: :class:`concurrent.futures.ProcessPoolExecutor` on all local cores (``workers`` to
  choose), started from a ``forkserver`` (``spawn`` where there is none) so workers never inherit MuJoCo's or
  Rich's threads: the server is a fresh single-threaded interpreter that imports the caller's task modules once
  (``preload``) and forks each worker from that, so a worker starts in milliseconds instead of importing MuJoCo,
  SciPy and the scenes itself (about 2.4 CPU-s each), and later pools of the same process reuse the server.
  No extra dependency.
- **Dask** (optional extra ``pip install "beambench[cluster]"``): ``scheduler="tcp://HOST:PORT"`` connects a
  ``distributed.Client`` to a running scheduler and uses its ``concurrent.futures`` executor
  (``Client.get_executor()``), so the calling code does not change. Start one with ``dask scheduler`` and
  ``dask worker tcp://HOST:8786 --nthreads 1`` on each machine (one thread per worker process: MuJoCo work
  holds the GIL between C calls).
- **SLURM**: ``cluster="slurm"`` builds a ``dask_jobqueue.SLURMCluster`` (options such as ``queue``,
  ``account``, ``cores``, ``memory``, ``walltime``, ``jobs`` from ``cluster_options`` or the
  ``jobqueue.slurm`` section of Dask's config, ``~/.config/dask/jobqueue.yaml``), scales it to ``jobs``
  jobs and connects a client to it. Run the sweep from a login node; results come back to it.

Work is submitted in *tasks* of several simulations each (:func:`chunks`; ~10–50) so that per-task overhead
(pickling, scheduling: ~1 ms locally, ~10 ms on Dask) stays a few percent of the compute.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import multiprocessing
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, TypeVar

from beambench.common.errors import BeambenchError

T = TypeVar("T")
R = TypeVar("R")


class ExecutorError(BeambenchError, RuntimeError):
    """The requested executor cannot be set up (missing extra, unreachable scheduler …): one-line message."""


MAX_LOCAL_WORKERS = 256  # local worker processes at most: more is a typo (each imports MuJoCo: ~150 MB)


def local_cores() -> int:
    """Cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


@dataclass
class Pool:
    """An executor with what callers size their work by: ``workers`` (parallel slots) and a ``label``."""

    executor: Executor
    workers: int
    label: str


@contextmanager
def make_executor(
    workers: int | None = None,
    scheduler: str | None = None,
    cluster: str | None = None,
    cluster_options: dict[str, Any] | None = None,
    connect_timeout_s: float = 10.0,
    preload: Sequence[str] = (),
) -> Iterator[Pool]:
    """The executor for a run; closes it (and any Dask client/cluster it made) on exit.

    ``workers``: local processes (default: all cores) or, with ``cluster``, jobs to request.
    ``scheduler``: a Dask scheduler address (``tcp://host:8786``). ``cluster``: ``"slurm"``.
    ``connect_timeout_s``: how long to try reaching the scheduler. ``preload``: modules the local workers' tasks
    live in, imported once in the fork server instead of once per worker.
    """
    if scheduler and cluster:
        raise ExecutorError("give either a scheduler address or a cluster, not both")
    if scheduler:
        client = _dask_client(scheduler, connect_timeout_s)
        try:
            yield Pool(client.get_executor(pure=False), _dask_slots(client), f"dask scheduler {scheduler}")
        finally:
            client.close()
        return
    if cluster:
        if cluster != "slurm":
            raise ExecutorError(f"cluster = {cluster!r}: only 'slurm' (via dask-jobqueue) is supported")
        try:
            from dask_jobqueue import SLURMCluster
            from distributed import Client
        except ImportError:
            raise ExecutorError("--cluster slurm needs the optional extra: pip install 'beambench[cluster]'") from None
        opts = dict(cluster_options or {})
        jobs = int(opts.pop("jobs", workers or 1))
        slurm = SLURMCluster(**opts)
        slurm.scale(jobs=jobs)
        client = Client(slurm)
        try:
            slots = jobs * int(opts.get("processes") or 1)
            yield Pool(client.get_executor(pure=False), slots, f"SLURM via dask-jobqueue, {jobs} jobs")
        finally:
            client.close()
            slurm.close()
        return
    n = workers or local_cores()
    if n < 1:
        raise ExecutorError(f"workers = {n}: must be >= 1")
    ctx = _worker_context(preload)
    started = ctx.SimpleQueue()  # each worker's pid, put there as it starts
    before = {p.pid for p in multiprocessing.active_children()}  # this process's children not of the pool
    pool = ProcessPoolExecutor(
        max_workers=n,
        mp_context=ctx,
        initializer=_worker_init,
        initargs=(os.getpid(), dict(os.environ), os.getcwd(), started),
    )
    try:
        yield Pool(pool, n, f"local process pool, {n} workers")
    except BaseException:  # Ctrl-C, a stop signal, an error: do not wait minutes for a running evaluation
        _stop_workers(pool, started, before)
        # the pool is broken now; its manager thread fails the pending futures itself (cancelling them as well
        # races it on Python 3.11: InvalidStateError in that thread)
        pool.shutdown(wait=True)
        raise
    pool.shutdown(wait=True, cancel_futures=True)


def _stop_workers(pool: ProcessPoolExecutor, started: Any, before: set[int | None], timeout_s: float = 5.0) -> None:
    """Terminate the pool's worker processes (SIGTERM, then SIGKILL after ``timeout_s``): a worker inside a long
    native simulation call would otherwise finish it before the pool could shut down. ``started`` holds the pid of
    every worker that has run its first line (:func:`_worker_init` puts it there); this process's children
    started since the pool (``before``: the ones before it) add the ones still starting (forked, not yet at their first line: left alone, each would run a whole task before the
    pool could end, or wake to find the pool's queues gone and print a traceback)."""
    if hasattr(pool, "terminate_workers"):  # Python >= 3.14
        pool.terminate_workers()
        return
    pids = {p.pid for p in multiprocessing.active_children() if p.pid is not None and p.pid not in before}
    while not started.empty():
        pids.add(started.get())
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in pids:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, sig)
        pids = {pid for pid in pids if not _ended(pid, timeout_s)}
        if not pids:
            return


def _ended(pid: int, timeout_s: float) -> bool:
    """Whether process ``pid`` ends within ``timeout_s`` (watched through a pidfd; without one, polled)."""
    if hasattr(os, "pidfd_open"):
        try:
            fd = os.pidfd_open(pid)
        except ProcessLookupError:
            return True
        try:
            return bool(select.select([fd], [], [], timeout_s)[0])
        finally:
            os.close(fd)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


def _worker_context(preload: Sequence[str]) -> multiprocessing.context.BaseContext:
    """``forkserver`` preloading ``preload`` (after :mod:`beambench.studies.worker_env`) where the platform has it
    and can watch the pool's owner from a worker (``os.pidfd_open``), else ``spawn``. The server starts with the
    first pool of a process, preloads what that pool's caller named, and lives until that process and its workers
    end; a module a later caller needs and the server lacks is imported by the worker itself."""
    if "forkserver" not in multiprocessing.get_all_start_methods() or not hasattr(os, "pidfd_open"):
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["beambench.studies.worker_env", *preload])
    return ctx


def _worker_init(owner: int, environ: dict[str, str], cwd: str, started: Any) -> None:
    """Worker initializer: its pid into ``started`` (the owner stops its workers by it), the owner's environment
    and working folder as they are now (a forked worker has the fork server's, from when that started: a per-user
    folder set since would be missed), then :func:`_die_with_owner`."""
    started.put(os.getpid())
    if dict(os.environ) != environ:
        os.environ.clear()
        os.environ.update(environ)
    if os.getcwd() != cwd:
        os.chdir(cwd)
    _die_with_owner(owner)


def _die_with_owner(owner: int) -> None:
    """The worker ends when the process that owns its pool (``owner``) dies, so that a killed
    sweep or calibration leaves no orphaned workers computing. The kernel kills it when its parent dies
    (``PR_SET_PDEATHSIG``: the owner under ``spawn``, the fork server under ``forkserver``); forked from a fork
    server, it also watches the owner through a pidfd from a daemon thread (the server outlives the owner while a
    worker holds its pipe, so the parent's death alone would come only after the running task)."""
    if os.getppid() != owner and hasattr(os, "pidfd_open"):
        try:
            fd = os.pidfd_open(owner)
        except ProcessLookupError:  # the owner is gone already
            os._exit(1)
        threading.Thread(target=_exit_when_readable, args=(fd,), name="beambench-owner-watch", daemon=True).start()
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() == 1:  # the parent died before the request took effect
        os._exit(1)


def _exit_when_readable(fd: int) -> None:
    """End this process at once when ``fd`` (a pidfd) becomes readable: the process it names has exited."""
    select.select([fd], [], [])
    os._exit(1)


def _dask_slots(client: Any) -> int:
    """Worker threads the scheduler knows of now (at least 1), over every worker: ``Client.nthreads()`` lists them
    all (``scheduler_info()`` lists only the first 5 in some Dask versions, 2025.7 among them)."""
    try:
        return max(1, sum(int(n) for n in client.nthreads().values()))
    except (OSError, TimeoutError, KeyError, TypeError, ValueError, AttributeError):  # busy scheduler: a guess
        return 8


def _dask_client(address: str, timeout_s: float):
    try:
        from distributed import Client
    except ImportError:
        raise ExecutorError("--scheduler needs Dask: pip install 'beambench[cluster]'") from None
    if not address.startswith(("tcp://", "tls://", "inproc://", "ws://", "wss://")):
        raise ExecutorError(f"--scheduler = {address!r}: expected an address such as tcp://HOST:8786")
    try:
        return Client(address, timeout=f"{timeout_s}s")
    except (OSError, TimeoutError) as exc:
        raise ExecutorError(f"--scheduler = {address!r}: cannot connect ({exc})") from None


def batch_size(n_items: int, workers: int, lo: int = 10, hi: int = 50, tasks_per_worker: int = 8) -> int:
    """Items per task: ~``tasks_per_worker`` tasks per worker for load balance, each of ``lo``…``hi`` items
    so that per-task overhead stays small — but never so large that a worker is left without a task."""
    if n_items <= 0:
        return lo
    w = max(1, workers)
    size = min(hi, max(lo, math.ceil(n_items / (w * tasks_per_worker))))
    return max(1, min(size, math.ceil(n_items / w)))


def chunks(items: Sequence[T], size: int) -> list[list[T]]:
    """``items`` cut into consecutive lists of at most ``size``."""
    size = max(1, int(size))
    return [list(items[i : i + size]) for i in range(0, len(items), size)]


def run_tasks(
    executor: Executor, fn: Callable[[T], R], tasks: Iterable[T], on_done: Callable[[T, R], None] | None = None
) -> list[R]:
    """Submit ``fn(task)`` for every task; call ``on_done(task, result)`` in the calling thread as each
    finishes (in completion order); return the results in task order. The first exception is re-raised after
    the pending tasks are cancelled (on a local process pool, :func:`make_executor` ends them)."""
    tasks = list(tasks)
    futures: dict[Future, int] = {executor.submit(fn, t): i for i, t in enumerate(tasks)}
    results: list[Any] = [None] * len(tasks)
    try:
        for fut in as_completed(futures):
            i = futures[fut]
            results[i] = fut.result()
            if on_done is not None:
                on_done(tasks[i], results[i])
    except BaseException:
        if not isinstance(executor, ProcessPoolExecutor):  # a local pool: make_executor stops its workers, and
            for fut in futures:  # its manager thread fails these futures (a cancelled one makes it raise on 3.11)
                fut.cancel()
        raise
    return results
