"""A sweep's later segments computed on a Dask cluster (``beambench run --scheduler tcp://HOST:PORT``).

With ``sim.segments: n`` the sim rig cuts its announced sweep into n parts (:mod:`beambench.backends.lookahead`).
The first part runs on the rig's own scene, on a local thread. With a scheduler, each later part's scene lives on
a Dask worker as an actor (:class:`SceneActor`, built there from the protocol's simulation slice) and the local
worker thread that drives it (:class:`RemoteScene`) makes the same calls in the same order: ``set_frequency``,
``advance_to``, the pre-settle. Each call returns the rows and the scene's state after it, so the run's data,
the cut checks and a run that leaves the schedule are the same as with local threads, bit for bit (the scene is
built from the same slice; the state is MuJoCo's full physics state with its warm start). Actors are spread over
the cluster's workers, one per worker while there are enough. Needs the ``cluster`` extra
(``pip install "beambench[cluster]"``).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from beambench.acquisition.capabilities import DeviceFault
from beambench.common.yaml_config import ConfigError
from beambench.sim.engine.stepping import Trajectory, quiet_mujoco_warnings
from beambench.sim.protocol_slice import SimSlice
from beambench.sim.scenes.drive import DrivenScene

SceneBuilder = Callable[[SimSlice], DrivenScene]  # how the rig builds its scene from the slice

CONNECT_TIMEOUT_S = 10.0


def connect(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> Any:
    """A ``distributed.Client`` of the scheduler at ``address``; a :class:`ConfigError` naming ``--scheduler``
    when Dask is missing, the address is not one or nothing answers there."""
    try:
        from distributed import Client
    except ImportError:
        raise ConfigError("<cli>", "--scheduler", address, "needs Dask: pip install 'beambench[cluster]'") from None
    if not address.startswith(("tcp://", "tls://", "inproc://", "ws://", "wss://")):
        raise ConfigError("<cli>", "--scheduler", address, "expected an address such as tcp://HOST:8786")
    try:
        return Client(address, timeout=f"{timeout_s}s")
    except (OSError, TimeoutError) as exc:
        raise ConfigError("<cli>", "--scheduler", address, f"cannot connect ({exc})") from None


class SceneActor:
    """On a Dask worker: the scene of ``sim`` (built as the rig builds its own), MuJoCo's warnings collected."""

    def __init__(self, sim: SimSlice, build: SceneBuilder) -> None:
        self._quiet = contextlib.ExitStack()
        self.warnings = self._quiet.enter_context(quiet_mujoco_warnings())
        self.scene = build(sim)
        self.cpu_s = 0.0  # CPU time of the calls (the actor's thread)

    def snapshot(self) -> tuple:
        return self.scene.snapshot()

    def set_frequency(self, hz: float) -> tuple[tuple, float]:
        c0 = time.thread_time()
        self.scene.set_frequency(hz)
        return self._after(c0)

    def advance_to(self, t_target: float) -> tuple[Trajectory, tuple, float]:
        c0 = time.thread_time()
        rows = self.scene.advance_to(t_target)
        return (rows, *self._after(c0))

    def presettle(self, hz: float, seconds: float, t_phys: float) -> tuple[dict[str, np.ndarray], tuple, float]:
        c0 = time.thread_time()
        row = self.scene.presettle(hz, seconds, t_phys)
        return (row, *self._after(c0))

    def _after(self, c0: float) -> tuple[tuple, float]:
        """The scene's state after a call and the CPU time of every call so far."""
        snap = self.scene.snapshot()
        self.cpu_s += time.thread_time() - c0
        return snap, self.cpu_s

    def close(self) -> None:
        self.scene.physics.close()
        self._quiet.close()


class RemoteScene:
    """The local handle of a :class:`SceneActor`: the calls a segment's worker makes (``SegmentScene``), each
    waiting for its result; :meth:`snapshot` is the state after the last call, kept from its answer, and
    :attr:`cpu_s` the CPU time the worker spent on the calls. A worker or cluster lost is a
    :class:`DeviceFault` (the runner idles the motor and keeps what was recorded)."""

    def __init__(self, client: Any, sim: SimSlice, build: SceneBuilder, worker: str | None = None) -> None:
        where = {"workers": [worker], "allow_other_workers": False} if worker else {}
        try:
            self._actor = client.submit(SceneActor, sim, build, actor=True, pure=False, **where).result()
        except Exception as exc:
            raise _lost(exc) from None
        self._snap: tuple = self._ask("snapshot")
        self.cpu_s = 0.0

    def _ask(self, method: str, *args: float) -> Any:
        try:
            return getattr(self._actor, method)(*args).result()
        except Exception as exc:
            raise _lost(exc) from None

    def set_frequency(self, hz: float) -> None:
        self._snap, self.cpu_s = self._ask("set_frequency", hz)

    def advance_to(self, t_target: float) -> Trajectory:
        rows, self._snap, self.cpu_s = self._ask("advance_to", t_target)
        return rows

    def presettle(self, hz: float, seconds: float, t_phys: float) -> dict[str, np.ndarray]:
        row, self._snap, self.cpu_s = self._ask("presettle", hz, seconds, t_phys)
        return row

    def snapshot(self) -> tuple:
        return self._snap

    def close(self) -> None:
        with contextlib.suppress(Exception):  # a cluster gone at the end loses nothing: the rows are here
            self._actor.close().result()


def _lost(exc: BaseException) -> DeviceFault:
    return DeviceFault(f"sim: the Dask worker computing a sweep segment failed ({type(exc).__name__}: {exc})")


def remote_scenes(client: Any, sim: SimSlice, n: int, build: SceneBuilder) -> list[RemoteScene]:
    """``n`` scenes of ``sim`` on the cluster, built by ``build`` (the rig's builder, sent by reference), one per
    worker in turn (by address). ``Client.nthreads()`` lists every worker (``scheduler_info()`` only the first 5 in some
    Dask versions, 2025.7 among them)."""
    workers = sorted(client.nthreads())
    return [RemoteScene(client, sim, build, workers[i % len(workers)] if workers else None) for i in range(n)]
