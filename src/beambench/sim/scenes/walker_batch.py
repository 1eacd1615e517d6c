"""Steady walking speed at many drive frequencies at once (the calibrator's and the benchmark's evaluator).

One settled walker (:class:`~beambench.sim.scenes.walker.WalkerSim`'s preroll) is copied into one rollout per
frequency; the controls are planned in advance (the ODrive's velocity ramp, then the rotor servo), so every
frequency runs in C, in one ``mujoco.rollout`` call per chunk, on ``nthread`` threads. The speed is the
least-squares slope of the body marker's x over ``record_s`` after the ramp plus ``settle_s`` — the same slope
``beambench analyze`` fits (``body_speed_mm_s``).

The speed needs ~3 s from rest to reach its steady value (23 / 65 Hz, measured: settle 0.6 s → −41 / +139 mm/s,
2 s → −58 / +170, 4 s → −63 / +175 at a 2.5 g foot), hence :data:`STEADY_SETTLE_S`.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Sequence
from dataclasses import replace

import mujoco
import numpy as np
from mujoco import rollout

from beambench.sim.models.beam import BeamModel
from beambench.sim.scene_params import WalkerParams
from beambench.sim.scenes.drive import KinematicServo, VelocityRamp
from beambench.sim.scenes.walker import WalkerSim
from beambench.sim.settings import SimSettings

STEADY_SETTLE_S = 3.0  # s after the ramp before the speed is steady (see the module docstring)
RECORD_S = 1.5
RAMP_RATE = 200.0  # turn/s²: the steady speed does not depend on it (10–200 agree within 0.2 mm/s)
CHUNK = 10_000  # steps per rollout call (bounds the state/sensor arrays)
STEADY_SETTINGS = SimSettings(settle_s=STEADY_SETTLE_S, record_s=RECORD_S, nthread=1)


def steady_speeds(
    beam: BeamModel,
    frequencies: Sequence[float],
    params: WalkerParams | None = None,
    *,
    settings: SimSettings = STEADY_SETTINGS,
    ramp_rate: float = RAMP_RATE,
    stride: int = 10,
) -> tuple[np.ndarray, np.ndarray]:
    """Forward body speed (mm/s) at each frequency and the mean body height (mm) over the record window; NaN
    where a run diverged. ``settings``: twist, timestep (None: the walker's), the settle time after the ramp,
    the record window, the integrator (None: the walker's) and threads (None: all cores); amplitude and noise
    do not apply."""
    twist_deg, timestep, settle_s, record_s = (
        settings.twist_deg,
        settings.timestep,
        settings.settle_s,
        settings.record_s,
    )
    if isinstance(timestep, tuple):
        raise ValueError("the walker takes one timestep for all frequencies")
    nthread = settings.nthread if settings.nthread is not None else (os.cpu_count() or 1)
    wp = replace(params or WalkerParams(), vel_ramp_rate=ramp_rate)
    sim = WalkerSim(beam, twist_deg, wp, integrator=settings.integrator or "implicitfast", timestep=timestep)
    m, d0 = sim.physics.model, sim.physics.data
    h = float(m.opt.timestep)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state0 = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d0, state0, spec)
    freqs = [float(f) for f in frequencies]
    t_on = np.array([abs(f) / ramp_rate + settle_s for f in freqs])
    nstep = int(np.ceil((t_on.max() + record_s) / h)) + 1
    inertia = wp.rotor_inertia + wp.eccentric_mass * wp.eccentric_radius**2
    ctrl = np.empty((len(freqs), nstep, 1))
    for i, f in enumerate(freqs):
        ramp = VelocityRamp(ramp_rate)
        ramp.setpoint = f
        servo = KinematicServo(m, "rotor_servo", inertia, wp.servo_hz, sim.integrator, h)
        _, theta = ramp.plan(nstep, h)
        ctrl[i, :, 0] = servo.controls(wp.spin * theta, h)[0]
    body = slice(int(m.sensor_adr[m.sensor("body").id]), int(m.sensor_adr[m.sensor("body").id]) + 3)
    models: mujoco.MjModel | list[mujoco.MjModel] = m
    if sim.damping is not None:  # a loss factor: each frequency's legs damped at that frequency
        models = [copy.copy(m) for _ in freqs]
        for model, f in zip(models, freqs):
            sim.damping.at(model, f)
    datas = [mujoco.MjData(m) for _ in range(max(1, min(nthread, len(freqs))))]
    state = np.repeat(state0[None], len(freqs), axis=0)
    warm: np.ndarray | None = np.repeat(d0.qacc_warmstart[None], len(freqs), axis=0)
    rows = []
    with rollout.Rollout(nthread=len(datas) if len(datas) > 1 else 0) as roll:
        for a in range(0, nstep, CHUNK):
            b = min(nstep, a + CHUNK)
            s_out, sens = roll.rollout(models, datas, state, ctrl[:, a:b], initial_warmstart=warm, nstep=b - a)
            rows.append(sens[:, ::stride, body])
            state, warm = s_out[:, -1], None
    sim.physics.close()
    pos = np.concatenate(rows, axis=1)
    t = np.arange(pos.shape[1]) * h * stride
    speed, height = np.full(len(freqs), np.nan), np.full(len(freqs), np.nan)
    for i in range(len(freqs)):
        sel = (t >= t_on[i]) & (t <= t_on[i] + record_s)
        if sel.sum() > 2 and np.all(np.isfinite(pos[i, sel])):
            speed[i] = 1e3 * float(np.polyfit(t[sel], pos[i, sel, 0], 1)[0])
            height[i] = 1e3 * float(pos[i, sel, 2].mean())
    return speed, height
