"""The local process pool (:func:`beambench.studies.executor.make_executor`): workers forked from a fork server
that imported the callers' task modules once and holds no thread, and that die with the pool's owner."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from beambench.studies.executor import make_executor
from conftest import descendants, process_alive, wait_until

pytestmark = pytest.mark.skipif(not hasattr(os, "pidfd_open"), reason="the fork server pool needs os.pidfd_open")


def test_workers_come_from_one_single_threaded_server_that_preloaded_the_simulation():
    # in a fresh process: the fork server is the first pool's of its process (whatever a test before made stays)
    code = textwrap.dedent(
        """
        import json, os
        from pathlib import Path
        from beambench.studies.executor import make_executor
        with make_executor(2, preload=("beambench.sim.scenes",)) as pool:
            servers = {f.result() for f in [pool.executor.submit(os.getppid) for _ in range(4)]}
            workers = {f.result() for f in [pool.executor.submit(os.getpid) for _ in range(4)]}
            server = min(servers)
            threads = [(t / "comm").read_text().strip() for t in Path(f"/proc/{server}/task").iterdir()]
            maps = Path(f"/proc/{server}/maps").read_text()
        with make_executor(1, preload=("beambench.sim.scenes",)) as pool:
            again = pool.executor.submit(os.getppid).result()
        print(json.dumps({"servers": sorted(servers), "workers": sorted(workers), "again": again, "owner": os.getpid(),
                          "threads": threads, "mujoco": "mujoco" in maps}))
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    seen = json.loads(out.stdout.splitlines()[-1])
    assert len(seen["servers"]) == 1 and seen["servers"] == [seen["again"]]  # a later pool reuses the server
    assert seen["servers"][0] != seen["owner"] and seen["owner"] not in seen["workers"]
    assert seen["threads"] == ["python"]  # no BLAS pool, no jemalloc purge thread: a clean fork
    assert seen["mujoco"]  # MuJoCo was imported in the server, once, not in each worker


def _asleep(pid: int) -> bool:
    """``pid`` is blocked in a sleep (``time.sleep``'s nanosleep, as the kernel's wait channel names it)."""
    return "nanosleep" in Path(f"/proc/{pid}/wchan").read_text()


def test_a_worker_mid_task_dies_with_the_pools_owner(tmp_path):
    """SIGKILL the process owning a pool while its worker sleeps in a task: the worker, the server and the
    resource tracker all end within seconds (the task would have run a minute)."""
    code = textwrap.dedent(
        """
        import os, time
        from beambench.studies.executor import make_executor
        with make_executor(1) as pool:
            worker = pool.executor.submit(os.getpid).result()
            fut = pool.executor.submit(time.sleep, 60)
            print(worker, flush=True)
            fut.result()
        """
    )
    owner = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert owner.stdout is not None
        worker = int(owner.stdout.readline())
        wait_until(lambda: _asleep(worker), 30, "the worker to sleep in its minute-long task")
        family = descendants(owner.pid)
        assert len(family) >= 3 and worker in family, family  # resource tracker, fork server, worker
    finally:
        owner.send_signal(signal.SIGKILL)
        owner.communicate()
    try:
        wait_until(lambda: not any(process_alive(p) for p in family), 10, "the pool's processes to end", 0.05)
    finally:
        for p in family:
            if process_alive(p):
                os.kill(p, signal.SIGKILL)


def test_workers_see_the_owners_environment_and_folder_as_they_are_when_the_pool_starts(tmp_path, monkeypatch):
    """As spawned workers would: a variable set (a per-user folder, say) or a folder changed into after the fork
    server started reaches the next pool's workers."""
    with make_executor(1) as pool:  # the server exists from here on
        pool.executor.submit(os.getpid).result()
    monkeypatch.setenv("BEAMBENCH_USER_DIR", str(tmp_path / "user"))
    monkeypatch.chdir(tmp_path)
    with make_executor(1) as pool:
        env = pool.executor.submit(os.getenv, "BEAMBENCH_USER_DIR").result()
        cwd = pool.executor.submit(os.getcwd).result()
    assert env == str(tmp_path / "user") and Path(cwd) == tmp_path


def test_an_error_in_the_pools_block_ends_a_worker_mid_task_at_once():
    """An error (or Ctrl-C) while a worker is inside a minute-long task: the pool stops its workers (SIGTERM) and
    the block ends within seconds, the worker gone."""
    t0 = time.monotonic()
    with pytest.raises(RuntimeError, match="stop"), make_executor(2) as pool:
        pids = {f.result() for f in [pool.executor.submit(os.getpid) for _ in range(8)]}
        for _ in range(2):
            pool.executor.submit(time.sleep, 60)
        raise RuntimeError("stop")
    assert time.monotonic() - t0 < 20  # the tasks would have taken 60 s
    assert pids and not any(process_alive(p) for p in pids), pids


def test_a_stop_while_the_workers_start_leaves_no_traceback():
    """A stop just after the first task was submitted, while the fork server is still starting the workers: a
    worker that has not yet run its first line (nor said its pid) is stopped as well, so none wakes to find the
    pool's queues gone and prints a traceback on the owner's stderr."""
    code = textwrap.dedent(
        """
        import time
        from beambench.studies.executor import make_executor
        with make_executor(1) as pool:  # the fork server is up from here on
            pool.executor.submit(time.sleep, 0).result()
        for _ in range(6):
            try:
                with make_executor(2) as pool:
                    pool.executor.submit(time.sleep, 60)
                    pool.executor.submit(time.sleep, 60)
                    raise RuntimeError("stop")
            except RuntimeError:
                pass
        print("done", flush=True)
        """
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.stdout.strip() == "done", proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr and "Error" not in proc.stderr, proc.stderr[-2000:]
