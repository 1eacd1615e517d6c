"""Chunked stepping of a MuJoCo model with precomputed per-step controls (``mujoco.rollout``).

The scene knows its controls in advance for each chunk (the stage reference follows the motor's planned
speed ramp), so a whole chunk runs in C with no Python per step. Each row of the returned trajectory is the
sensor readout of the state *before* step k, at time ``t0 + k·h`` (mujoco.rollout evaluates sensors before it
integrates; its state rows are one step later, so only sensors are used and the two are never mixed).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np
from mujoco import rollout

INTEGRATORS = {
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
    "discrete": mujoco.mjtIntegrator.mjINT_DISCRETE,
}


def integrator_enum(name: str) -> mujoco.mjtIntegrator:
    """MuJoCo's integrator for ``name`` (a key of :data:`INTEGRATORS`); a clear ValueError otherwise."""
    if name not in INTEGRATORS:
        raise ValueError(f"integrator = {name!r}: one of {', '.join(INTEGRATORS)}")
    return INTEGRATORS[name]


MAX_CHUNK_STEPS = 20_000  # rollout allocates nstep × nstate; bound the memory of one call


@dataclass
class Trajectory:
    """Rows at times ``t`` (true simulated time, s) with named channels ``[n, ...]``."""

    t: np.ndarray
    channels: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t)

    @staticmethod
    def concat(parts: list[Trajectory]) -> Trajectory:
        parts = [p for p in parts if len(p)]
        if not parts:
            raise ValueError("no rows")
        keys = parts[0].channels.keys()
        return Trajectory(
            np.concatenate([p.t for p in parts]), {k: np.concatenate([p.channels[k] for p in parts]) for k in keys}
        )

    def tail(self, n: int) -> Trajectory:
        return Trajectory(self.t[-n:], {k: v[-n:] for k, v in self.channels.items()})


class Physics:
    """A compiled model and its data, advanced in chunks through ``mujoco.rollout``."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self._spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self._roll = rollout.Rollout(nthread=0)
        self._state = np.empty(mujoco.mj_stateSize(model, self._spec))
        # called with the new timestep after every change (a scene whose model depends on it: matched contacts)
        self.on_timestep: Callable[[float], None] | None = None
        self.sensor_slices = {
            mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SENSOR, i): slice(int(a), int(a + d))
            for i, (a, d) in enumerate(zip(model.sensor_adr, model.sensor_dim))
        }

    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def timestep(self) -> float:
        return float(self.model.opt.timestep)

    def set_timestep(self, h: float) -> None:
        if h != self.model.opt.timestep and self.on_timestep is not None:
            self.on_timestep(h)
        self.model.opt.timestep = h

    def snapshot(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Everything needed to redo the next chunk: full physics state, warm start, timestep."""
        state = np.empty_like(self._state)
        mujoco.mj_getState(self.model, self.data, state, self._spec)
        return state, self.data.qacc_warmstart.copy(), self.timestep

    def restore(self, snap: tuple[np.ndarray, np.ndarray, float]) -> None:
        state, warm, h = snap
        mujoco.mj_setState(self.model, self.data, state, self._spec)
        self.data.qacc_warmstart[:] = warm
        self.set_timestep(h)

    def reset_to_equilibrium(self, seconds: float, ctrl: np.ndarray) -> None:
        """Let the model settle under gravity with constant ``ctrl``, then set time to zero."""
        n = round(float(seconds / self.timestep))
        self.data.ctrl[:] = ctrl
        if n:
            self.step(np.tile(ctrl, (n, 1)))
        self.data.time = 0.0
        self.data.qvel[:] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def step(self, ctrl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Apply ``ctrl[k]`` during step k; returns (row times [n], sensordata [n, nsensordata])."""
        n = len(ctrl)
        m, d = self.model, self.data
        t0, h = float(d.time), self.timestep
        sens = np.empty((n, m.nsensordata))
        for a in range(0, n, MAX_CHUNK_STEPS):
            b = min(n, a + MAX_CHUNK_STEPS)
            mujoco.mj_getState(m, d, self._state, self._spec)
            warm = d.qacc_warmstart.copy()
            _, s = self._roll.rollout(
                m, d, self._state[None], ctrl[None, a:b], initial_warmstart=warm[None], nstep=b - a
            )
            sens[a:b] = s[0]
            # rollout leaves ``d`` at the final state of the chunk: continue from there
        times = t0 + h * np.arange(n)
        return times, sens

    def close(self) -> None:
        self._roll.close()


_quiet_lock = threading.Lock()
_quiet_sinks: list[list[str]] = []  # the message lists of the open quiet_mujoco_warnings() contexts
_quiet_previous: Any = None


def _collect_warning(message: str) -> None:
    for sink in list(_quiet_sinks):
        sink.append(message)


@contextlib.contextmanager
def quiet_mujoco_warnings() -> Iterator[list[str]]:
    """Collect MuJoCo's warnings (diverging configurations are expected here) instead of printing them and
    appending them to MUJOCO_LOG.TXT in the working directory; yields the list of messages.

    MuJoCo's warning handler is process-wide: nested and concurrent contexts (threads) share one handler,
    installed by the first to enter and restored by the last to leave; each context sees every message."""
    global _quiet_previous
    messages: list[str] = []
    with _quiet_lock:
        if not _quiet_sinks:
            _quiet_previous = mujoco.get_mju_user_warning()
            mujoco.set_mju_user_warning(_collect_warning)
        _quiet_sinks.append(messages)
    try:
        yield messages
    finally:
        with _quiet_lock:
            del _quiet_sinks[next(i for i, m in enumerate(_quiet_sinks) if m is messages)]
            if not _quiet_sinks:
                mujoco.set_mju_user_warning(_quiet_previous)
                _quiet_previous = None
