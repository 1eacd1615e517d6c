"""The release test (paper Sec. II-B "Model fitting", Fig. 2k): a clamped beam with a load hanging from its tip is
let go, and three markers on the tip record it returning to rest.

Frame as the contact rig: the clamp at the origin, the beam along +y, z up, gravity −z; the load pulls the tip
straight down (a world-fixed force m·g on the tip site, so the loaded state is the static equilibrium under the
hanging weight). Markers ``tip1``/``tip2`` sit ±8 mm along the tip section's width, ``tip3`` 6 mm off its
face (a rigid marker tree on the tip section, rotated with the twist); ``stage`` marks the clamp.

Two ways in:

- **Python, fast** — :func:`release_batch` releases many beams at once (one compiled model per parameter set,
  started from its loaded static equilibrium, stepped with ``mujoco.rollout`` on all cores) and returns the
  marker paths; :func:`simulate_release` is the one-beam convenience. The fit (:mod:`beambench.studies.fit.release`) uses these.
- **Sessions** — :class:`ReleaseSim` is the ``rig: release`` scene of the sim backend
  (``beambench run protocols/release_test.yaml``): the load hangs through the settle time and a short part
  of the record window, then is released (:func:`release_time`); motor idle, load cells read nothing.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import mujoco
import numpy as np
from mujoco import rollout

from beambench.acquisition.protocol.scenes import RELEASE
from beambench.sim.engine.stepping import Physics, integrator_enum, quiet_mujoco_warnings
from beambench.sim.models.beam import BeamModel, add_beam
from beambench.sim.models.params import BeamParams
from beambench.sim.models.registry import default_params, make_beam_model
from beambench.sim.scene_params import RigParams
from beambench.sim.scenes.drive import DrivenScene, VelocityRamp
from beambench.sim.scenes.registry import SceneConfig, register

G = 9.81
RELEASE_MARKERS = RELEASE.markers  # stage, tip1, tip2, tip3
TIP_MARKERS = RELEASE_MARKERS[1:]
MARKER_HALF_SPAN = 0.008  # m, tip1/tip2 from the section centre along the width
MARKER_STANDOFF = 0.006  # m, tip3 from the section centre along the thickness normal
DEFAULT_TIMESTEP = 1e-4
RELEASE_DELAY_S = 0.1  # the load is let go this long after the record window opens (capped at record_s / 4)
MAX_CHUNK_STEPS = 20_000
CHECK_S = 0.02  # release_batch checks every this much simulated time which runs have come to rest
REST_TOL_M = 1e-7  # ... a run whose markers moved less than this over a whole check interval
LOAD_STEPS = 4  # static_equilibrium hangs the load in this many increments (a soft rod has several equilibria)


def marker_offsets(twist_deg: float) -> np.ndarray:
    """Tip marker positions [3, 3] in the tip body frame (= clamp frame at rest): on the tip section, whose
    width direction is the root's (+z) turned by φ about the beam axis (+y)."""
    ph = math.radians(twist_deg)
    width = np.array([math.sin(ph), 0.0, math.cos(ph)])
    normal = np.array([math.cos(ph), 0.0, -math.sin(ph)])
    return np.stack([MARKER_HALF_SPAN * width, -MARKER_HALF_SPAN * width, MARKER_STANDOFF * normal])


def build_release_spec(
    beam: BeamModel,
    twist_deg: float = 90.0,
    integrator: str = "implicitfast",
    timestep: float = DEFAULT_TIMESTEP,
    markers: int = 3,
) -> mujoco.MjSpec:
    """Clamp (fixed) → beam → tip markers; actuator ``load`` (ctrl = hanging weight in N, pulls the tip down
    in the world frame); framepos sensors named like the markers (``stage``, ``tip1`` …)."""
    integrator_id = integrator_enum(integrator)
    spec = mujoco.MjSpec()
    spec.modelname = "beambench_release_test"
    spec.option.timestep = timestep
    spec.option.integrator = integrator_id
    spec.option.gravity = [0, 0, -G]
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    world = spec.worldbody
    world.add_site(name="world", size=[0.001, 0, 0])  # reference frame of the load's direction
    clamp = world.add_body(name="clamp")
    clamp.add_site(name="stage", size=[0.002, 0, 0])
    sites = add_beam(clamp, beam, twist_deg)
    tip = spec.body(sites.tip_body)
    names = TIP_MARKERS[:markers]
    for name, off in zip(names, marker_offsets(twist_deg)):
        tip.add_site(name=name, pos=list(off), size=[0.0015, 0, 0], rgba=[1, 1, 1, 1])
    spec.add_actuator(
        name="load", target=sites.tip_site, trntype=mujoco.mjtTrn.mjTRN_SITE, refsite="world", gear=[0, 0, -1, 0, 0, 0]
    )
    for name in ("stage", *names):
        spec.add_sensor(
            name=name, type=mujoco.mjtSensor.mjSENS_FRAMEPOS, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=name
        )
    return spec


def static_equilibrium(
    model: mujoco.MjModel,
    load_n: float,
    qpos: np.ndarray | None = None,
    tol: float = 1e-11,
    max_iter: int = 60,
    load_steps: int = LOAD_STEPS,
) -> np.ndarray:
    """Joint positions where springs, gravity and the tip load balance (Newton with a finite-difference
    Jacobian and backtracking; hinge-only models), the load hung in ``load_steps`` equal increments, each solved
    from the last. A soft rod under the 200 g load has several equilibria (bent down, or twisted up sideways):
    one Newton solve from the straight beam lands on either, flipping between neighbouring moduli 0.1 % apart
    (tip 20 mm apart); loading gradually follows the branch a hung weight takes, continuous in the parameters."""
    if model.nq != model.nv:
        raise ValueError("static_equilibrium: hinge/slide joints only (nq == nv)")
    q = model.qpos0.copy() if qpos is None else np.array(qpos, float)
    if qpos is None and load_steps > 1 and load_n != 0:
        for fraction in np.arange(1, load_steps) / load_steps:
            q = _newton_equilibrium(model, fraction * load_n, q, tol, max_iter)
    return _newton_equilibrium(model, load_n, q, tol, max_iter)


def _newton_equilibrium(model: mujoco.MjModel, load_n: float, q: np.ndarray, tol: float, max_iter: int) -> np.ndarray:
    """One Newton solve of the static balance from ``q``."""
    d = mujoco.MjData(model)
    d.ctrl[:] = load_n
    q = q.copy()

    def residual(x: np.ndarray) -> np.ndarray:
        d.qpos[:] = x
        d.qvel[:] = 0.0
        mujoco.mj_forward(model, d)
        return d.qfrc_passive + d.qfrc_actuator - d.qfrc_bias

    r = residual(q)
    nv, eps = model.nv, 1e-7
    jac = np.empty((nv, nv))
    for _ in range(max_iter):
        if np.max(np.abs(r)) < tol:
            break
        for i in range(nv):
            q[i] += eps
            jac[:, i] = (residual(q) - r) / eps
            q[i] -= eps
        try:
            step = np.linalg.solve(jac, -r)
        except np.linalg.LinAlgError:
            step = np.linalg.lstsq(jac, -r, rcond=None)[0]
        a, norm = 1.0, np.linalg.norm(r)
        while True:
            qn = q + a * step
            rn = residual(qn)
            if np.linalg.norm(rn) < norm or a < 1e-4:
                break
            a *= 0.5
        q, r = qn, rn
    return q


def _sensor_index(model: mujoco.MjModel, names: Sequence[str]) -> np.ndarray:
    return np.concatenate([np.arange(3) + int(model.sensor(n).adr[0]) for n in names])


@dataclass
class ReleaseBatch:
    """Marker paths after the release: ``markers`` [nrun, n, M, 3] (m, world) at ``t`` [n] (s from the
    release); ``loaded``/``rest`` [nrun, M, 3] the static marker positions under the load and without it;
    ``ok`` False where a run diverged."""

    t: np.ndarray
    markers: np.ndarray
    names: tuple[str, ...]
    loaded: np.ndarray
    rest: np.ndarray
    ok: np.ndarray


def release_models(
    beams: Sequence[BeamModel],
    twist_deg: float = 90.0,
    integrator: str = "implicitfast",
    timestep: float = DEFAULT_TIMESTEP,
    markers: int = 3,
) -> list[mujoco.MjModel]:
    """One compiled release scene per beam (compiling PRB3 takes ~1 ms)."""
    return [build_release_spec(b, twist_deg, integrator, timestep, markers).compile() for b in beams]


def release_batch(
    models: Sequence[mujoco.MjModel],
    load_n: float,
    duration_s: float,
    names: Sequence[str] = TIP_MARKERS,
    nthread: int | None = None,
    with_rest: bool = False,
    roller: rollout.Rollout | None = None,
    rest_tol_m: float | None = REST_TOL_M,
) -> ReleaseBatch:
    """Release every model (same size signature and timestep) from its loaded equilibrium and record the
    markers ``names`` at every step for ``duration_s``. Runs on ``nthread`` threads (default: all cores), or
    on the thread pool of ``roller`` (a ``mujoco.rollout.Rollout`` kept across calls).

    Stepping goes in chunks of ``CHECK_S``; a run whose markers stayed within ``rest_tol_m`` of their last
    position over a whole chunk has come to rest and stops there, its remaining rows holding that position
    (None: always step to the end)."""
    nrun = len(models)
    m0 = models[0]
    h = float(m0.opt.timestep)
    n = max(2, math.ceil(duration_s / h - 1e-9) + 1)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    nstate = mujoco.mj_stateSize(m0, spec)
    state = np.empty((nrun, nstate))
    loaded = np.empty((nrun, len(names), 3))
    rest = np.full((nrun, len(names), 3), np.nan)
    idx = _sensor_index(m0, names)
    for i, m in enumerate(models):
        d = mujoco.MjData(m)
        if with_rest:
            d.qpos[:] = static_equilibrium(m, 0.0)
            mujoco.mj_forward(m, d)
            rest[i] = d.sensordata[idx].reshape(-1, 3)
        d.qpos[:] = static_equilibrium(m, load_n)
        d.qvel[:] = 0.0
        d.ctrl[:] = 0.0
        mujoco.mj_forward(m, d)
        loaded[i] = d.sensordata[idx].reshape(-1, 3)
        mujoco.mj_getState(m, d, state[i], spec)
    own = roller is None
    if roller is None:
        threads = max(1, min(nrun, nthread or os.cpu_count() or 1))
        roller = rollout.Rollout(nthread=threads if threads > 1 else 0)
    threads = max(1, roller.nthread)
    datas = [mujoco.MjData(m0) for _ in range(threads)] if roller.nthread > 0 else mujoco.MjData(m0)
    out = np.empty((nrun, n, len(names), 3))
    ok = np.ones(nrun, bool)
    active = np.arange(nrun)
    chunk = max(2, round(CHECK_S / h)) if rest_tol_m is not None else MAX_CHUNK_STEPS
    try:
        with quiet_mujoco_warnings():  # a diverging run is reported in ``ok``, not printed and logged to a file
            a = 0
            while a < n and len(active):
                b = min(n, a + chunk)
                st, sd = roller.rollout([models[int(i)] for i in active], datas, state[active], None, nstep=b - a)
                rows = sd[:, :, idx].reshape(len(active), b - a, len(names), 3)
                out[active, a:b] = rows
                state[active] = st[:, -1]
                # rollout stops a run that warns (diverges) and repeats its last state: its clock falls behind
                ok[active] &= np.abs(st[:, -1, 0] - b * h) < 0.5 * h
                if rest_tol_m is not None and b < n:
                    still = np.abs(rows - rows[:, -1:]).max(axis=(1, 2, 3)) < rest_tol_m
                    done = active[still | ~ok[active]]
                    out[done, b:] = out[done, b - 1 : b]
                    active = active[~(still | ~ok[active])]
                a = b
    finally:
        if own:
            roller.close()
    ok &= np.isfinite(out).all(axis=(1, 2, 3)) & (np.abs(out).max(axis=(1, 2, 3)) < 1.0)
    return ReleaseBatch(np.arange(n) * h, out, tuple(names), loaded, rest, ok)


def simulate_release(
    params: BeamParams | str = "paper",
    model: str = "prb3",
    twist_deg: float = 90.0,
    load_g: float = 200.0,
    duration_s: float = 0.3,
    timestep: float = DEFAULT_TIMESTEP,
    integrator: str = "implicitfast",
) -> ReleaseBatch:
    """One release test from a parameter set (name or :class:`BeamParams`): tip marker paths, rest and
    loaded positions (a batch of one)."""
    p = default_params(model, params) if isinstance(params, str) else params
    m = release_models([make_beam_model(model, p)], twist_deg, integrator, timestep)
    return release_batch(m, load_g * 1e-3 * G, duration_s, nthread=1, with_rest=True)


def release_time(settle_s: float, record_s: float) -> float:
    """When a session lets go of the load: a little into the first record window (so the window shows the
    loaded hold, the release and the return to rest)."""
    return settle_s + min(RELEASE_DELAY_S, record_s / 4)


class ReleaseSim(DrivenScene):
    """The ``rig: release`` scene: channels ``markers`` [n, 1 + k, 3] (stage, tip1 … tipk), ``force_nt``
    (zeros: no plate) and the motor's ``theta``/``omega``/``setpoint`` (the motor drives nothing here)."""

    rig: RigParams

    def __init__(
        self,
        beam: BeamModel,
        twist_deg: float = 90.0,
        load_g: float = 200.0,
        markers: int = 3,
        release_s: float = 0.6,
        integrator: str = "implicitfast",
        timestep: float | None = None,
    ) -> None:
        self.beam, self.twist_deg, self.load_g, self.release_s = beam, twist_deg, load_g, release_s
        self.integrator = integrator
        self.markers = RELEASE_MARKERS[: 1 + markers]
        self.rig = RigParams()  # motor constants for the (idle) motor's telemetry
        self.load_n = load_g * 1e-3 * G
        self.spec = build_release_spec(beam, twist_deg, integrator, timestep or DEFAULT_TIMESTEP, markers)
        model = self.spec.compile()
        super().__init__(Physics(model))
        self.ramp = VelocityRamp(self.rig.vel_ramp_rate)
        d = self.physics.data
        d.qpos[:] = static_equilibrium(model, self.load_n)
        d.qvel[:] = 0.0
        d.ctrl[:] = self.load_n
        d.time = 0.0
        mujoco.mj_forward(model, d)

    def set_frequency(self, hz: float) -> None:
        self.ramp.setpoint = float(hz)

    def _plan(self, n: int, h: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        omega, theta = self.ramp.plan(n, h)
        t = self.physics.time + h * np.arange(n)
        ctrl = np.where(t < self.release_s - 1e-12, self.load_n, 0.0)
        motor = {"theta": theta[:-1], "omega": omega[:-1], "setpoint": np.full(n, self.ramp.setpoint)}
        return ctrl[:, None], motor

    def _channels(self, sens: np.ndarray) -> dict[str, np.ndarray]:
        n = len(sens)
        markers = np.stack([self.sensor(sens, m) for m in self.markers], axis=1)
        return {"markers": markers, "force_nt": np.zeros((n, 2))}

    def motor_torque(self, channels: dict[str, np.ndarray]) -> np.ndarray:
        """Nothing is connected to the motor: friction only."""
        return self.rig.friction_torque * np.tanh(channels["omega"] / 0.05)

    def identity(self) -> dict[str, Any]:
        m = self.physics.model
        return {
            "scene": "release_test",
            **self.beam.describe(),
            "twist_deg": self.twist_deg,
            "load_g": self.load_g,
            "load_direction": [0.0, 0.0, -1.0],
            "release_time_s": self.release_s,
            "markers": list(self.markers),
            "marker_offsets_m": {n: o.tolist() for n, o in zip(TIP_MARKERS, marker_offsets(self.twist_deg))},
            "integrator": self.integrator,
            "timestep": self.physics.timestep,
            "timestep_policy": "fixed",
            "nq": int(m.nq),
            "nv": int(m.nv),
            "rig_params": asdict(self.rig),
            "mujoco_version": mujoco.__version__,
        }


# --- scene registration (beambench.sim.scenes.registry) --------------------------------------------------------
@register(RELEASE)
def build(cfg: SceneConfig) -> ReleaseSim:
    """The release test of a protocol: its load and markers (``release:``), released early in the record window."""
    sim = cfg.sim
    return ReleaseSim(
        cfg.beam,
        twist_deg=sim.settings.twist_deg,
        load_g=sim.release.load_g,
        markers=sim.release.markers,
        release_s=release_time(sim.settings.settle_s, sim.settings.record_s),
        integrator=sim.integrator,
        timestep=sim.timestep,
    )
