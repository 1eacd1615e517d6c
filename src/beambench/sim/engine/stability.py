"""Why an explicit integrator diverges on a model: the linearised model's stiffest mode against the
integrator's stability region.

MuJoCo's ``RK4`` is fully explicit: joint damping, stiffness and actuator terms all enter explicitly. A beam
joint with damping ``b`` on a light link has an overdamped mode at λ ≈ −b/I (PRB3 with the paper's values:
about −8.8e4 1/s), far faster than any vibration of the beam. RK4 is stable only where its amplification
|1 + z + z²/2 + z³/6 + z⁴/24| ≤ 1 at z = h·λ for every mode (on the negative real axis: h·|λ| ≤ 2.785), so such a
model needs a timestep of a few 10 µs under RK4, while ``euler`` (damping implicit), ``implicitfast`` and
``implicit`` are stable far beyond. :func:`unstable_reason` says this in words for a run MuJoCo stopped.
"""

from __future__ import annotations

import mujoco
import numpy as np

EXPLICIT = ("rk4",)  # integrators whose stability the linearised modes decide (MuJoCo's Euler damps implicitly)


def rk4_amplification(z: np.ndarray) -> np.ndarray:
    """|R(z)| of classical RK4 (R = 1 + z + z²/2 + z³/6 + z⁴/24); a mode with |R(hλ)| > 1 grows every step."""
    z = np.asarray(z, complex)
    return np.abs(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24)


def modes(model: mujoco.MjModel, qpos: np.ndarray | None = None, eps: float = 1e-6) -> np.ndarray:
    """Eigenvalues (1/s) of the model's dynamics linearised at ``qpos`` (default: qpos0) at rest, controls zero:
    the finite-difference Jacobian of (q̇, q̈) with respect to (q, q̇)."""
    d = mujoco.MjData(model)
    d.qpos[:] = model.qpos0 if qpos is None else qpos
    mujoco.mj_forward(model, d)
    q0, a0, nv = d.qpos.copy(), d.qacc.copy(), model.nv
    da_dq, da_dv = np.zeros((nv, nv)), np.zeros((nv, nv))
    for i in range(nv):
        dq = np.zeros(nv)
        dq[i] = eps
        d.qpos[:] = q0
        mujoco.mj_integratePos(model, d.qpos, dq, 1.0)
        d.qvel[:] = 0
        mujoco.mj_forward(model, d)
        da_dq[:, i] = (d.qacc - a0) / eps
        d.qpos[:] = q0
        d.qvel[:] = 0
        d.qvel[i] = eps
        mujoco.mj_forward(model, d)
        da_dv[:, i] = (d.qacc - a0) / eps
    a = np.block([[np.zeros((nv, nv)), np.eye(nv)], [da_dq, da_dv]])
    return np.linalg.eigvals(a)


def rk4_max_timestep(lam: np.ndarray) -> float:
    """The largest timestep (s) at which every mode ``lam`` stays inside RK4's stability region."""
    lam = np.asarray(lam, complex)
    lam = lam[np.abs(lam) > 0]
    if not len(lam):
        return float("inf")
    lo, hi = 0.0, 3.0 / float(np.max(np.abs(lam)))  # |hλ| ≤ 2.83 inside the region anywhere
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.all(rk4_amplification(mid * lam) <= 1 + 1e-9) else (lo, mid)
    return lo


def unstable_reason(model: mujoco.MjModel, integrator: str, qpos: np.ndarray | None = None) -> str:
    """One sentence on why MuJoCo stopped a run of ``model`` at its timestep with ``integrator``."""
    h = float(model.opt.timestep)
    if integrator not in EXPLICIT:
        return f"MuJoCo flagged the {integrator} run unstable at dt {h:g} s (NaN or huge acceleration)"
    lam = modes(model, qpos)
    h_max = rk4_max_timestep(lam)
    worst = lam[np.argmax(rk4_amplification(h * lam))]
    real = abs(worst.imag) < 1e-6 * abs(worst)
    kind = "overdamped joint damping on a light link" if real else f"a {abs(worst.imag) / (2 * np.pi):.3g} Hz mode"
    shown = f"{worst.real:.3g}" if real else f"{worst.real:.3g}{worst.imag:+.3g}j"
    if h <= h_max:
        return f"MuJoCo flagged the rk4 run unstable at dt {h:g} s, inside RK4's linear stability limit {h_max:.2g} s"
    return f"explicit RK4 is unstable at dt {h:g} s: the model's stiffest mode (λ = {shown} 1/s, {kind}) needs dt ≤ {h_max:.2g} s; implicitfast/implicit/euler damp it"
