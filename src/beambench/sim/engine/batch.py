"""Batched stepping: many models (or one model at many settings) on a thread pool with ``mujoco.batch``."""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence

import mujoco
import numpy as np
from mujoco.batch import Batch

from beambench.sim.engine.stepping import quiet_mujoco_warnings

CHUNK_ROWS = 500_000  # sensor rows (nsim × nstep) per Batch.rollout call, bounds memory


def thread_count(nthread: int | None, nrun: int) -> int:
    """Threads for ``nrun`` runs: ``nthread`` if given, else every core, never more than the runs."""
    cores = os.cpu_count() or 1
    return max(1, min(nrun, nthread if nthread else cores))


def rollout_batch(
    models: Sequence[mujoco.MjModel],
    qpos0: np.ndarray,
    qvel0: np.ndarray,
    controls: Callable[[int, int], np.ndarray],
    n_total: int,
    keep: np.ndarray,
    nthread: int | None = None,
    on_chunk: Callable[[int, np.ndarray], None] | None = None,
    timing: dict | None = None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Step model i from (qpos0[i], qvel0[i]) for ``n_total`` steps on a thread pool; ``controls(k0, n)``
    gives the controls [nrun, n, nu] of steps k0..k0+n−1. Returns the sensor rows at the step indices
    ``keep`` ([nrun, len(keep), nsensordata]; row k is evaluated before step k, at time k·h), ``ok`` [nrun]
    (False: MuJoCo warned — an unstable run — and stopped stepping it) and the wall seconds spent stepping.
    ``on_chunk(k0, rows)`` sees every chunk's full-resolution sensor rows [nrun, n, nsensordata];
    ``timing`` (a dict) accumulates ``wall`` and calling-thread ``cpu`` seconds of the stepping alone.
    All models share one size signature and timestep."""
    nrun = len(models)
    m0 = models[0]
    batch = Batch(m0, nsim=nrun, nthread=thread_count(nthread, nrun))
    if any(m is not m0 for m in models):
        batch.set_models(list(models))
    batch.reset(stage=mujoco.mjtStage.mjSTAGE_NONE)
    batch.qpos[:] = qpos0
    batch.qvel[:] = qvel0
    batch.forward()
    out = np.full((nrun, len(keep), m0.nsensordata), np.nan)
    chunk = max(1, min(n_total, CHUNK_ROWS // nrun))
    wall, k0 = 0.0, 0
    while k0 < n_total:
        n = min(chunk, n_total - k0)
        ctrl = controls(k0, n)
        t0, c0 = time.perf_counter(), time.thread_time()
        with quiet_mujoco_warnings():  # a diverging run is reported in ``ok``, not printed and logged to a file
            sd = batch.rollout(n, control=ctrl, record=("sensordata",))["sensordata"]
        wall += time.perf_counter() - t0
        if timing is not None:
            timing["wall"] = timing.get("wall", 0.0) + time.perf_counter() - t0
            timing["cpu"] = timing.get("cpu", 0.0) + time.thread_time() - c0
        sel = (keep >= k0) & (keep < k0 + n)
        if sel.any():
            out[:, sel, :] = sd[:, keep[sel] - k0, :]
        if on_chunk is not None:
            on_chunk(k0, sd)
        k0 += n
    warn = np.asarray(batch.warning)
    ok = warn.reshape(nrun, -1).sum(axis=1) == 0 if warn.size else np.ones(nrun, bool)
    return out, ok, wall


def window(settle_s: float, record_s: float, h: float, sample_every: int = 1) -> tuple[int, np.ndarray]:
    """Steps to run and the recorded step indices: every ``sample_every``-th step time in
    [settle_s, settle_s + record_s), whatever h divides."""
    n_settle = math.ceil(settle_s / h - 1e-9)
    n_total = max(n_settle + 1, math.ceil((settle_s + record_s) / h - 1e-9))
    return n_total, np.arange(n_settle, n_total, sample_every)
