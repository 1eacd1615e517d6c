"""Thermal drift of the beam's stiffness: the beam warms with the mechanical energy the drive puts into it and
cools toward ambient; its joint springs soften with the temperature rise (off unless ``sim.thermal_drift``).

Model (a lumped first-order body; one temperature for the whole beam)::

    C · dΔT/dt = η · P − C · ΔT / τ          k(t) = k₀ · max(1 − α · ΔT, K_FLOOR)

- ``P``: the mean mechanical power the stage delivers to the beam over a chunk of physics, −F_beam→stage · v_stage
  (5–12 mW on the contact rig at 2 mm, 8–20 Hz). At a steady state it is all dissipated, in the beam's damping
  and at the foot's contacts; ``η`` (``heated_fraction``, default 1) is the share that heats the beam.
- ``C`` (``heat_capacity_j_per_k``): the beam's heat capacity, by default its mass × c_p of TPU, 1.8 kJ/(kg·K)
  (a thermoplastic polyurethane's specific heat is 1.7–1.9 kJ/(kg·K)): 9.3 J/K for the paper's 5.17 g beam.
- ``τ`` (``tau_s``): the cooling time constant. A strip of thickness d cooled from both faces by natural
  convection (h ≈ 5–15 W/(m²·K)) has τ = ρ·c_p·(d/2)/h: 40–130 s for 0.5 mm of TPU (ρ 1.2 t/m³).
- ``α`` (``alpha_per_k``): the relative fall of the stiffness per kelvin. Above their glass transition TPUs lose
  roughly 0.5–2 % of their modulus per kelvin near room temperature (dynamic mechanical analysis of polyether
  and polyester TPUs); 1 %/K by default.
- ``K_FLOOR``: the stiffness never falls below half its cold value (the linear law is for small rises).

With the physical defaults the beam's own dissipation is too small to matter: at 16 Hz (8 mW) it warms by
0.086 K at steady state and softens by 0.09 % (measured: 0.082 K after 300 s). A rig whose beam drifts measurably
is heated from elsewhere (the motor and clamp, the room); ``heat_capacity_j_per_k`` and ``heated_fraction`` then
act as effective parameters. A test compresses hours into seconds with a small ``C``: the same equation.

Applied between chunks of physics (each ``advance_to``, at most the sim clock's chunk, 0.1 s or a step's
settle/record window when shorter): the stiffness is constant within a chunk, ΔT is updated after it with the
exact solution for constant P over the chunk. The damping (``b``) is left unchanged. Only the bending and twist
hinges of the beam (joints named ``beam…``) are scaled; the stage slider and foot are not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

CP_TPU = 1800.0  # J/(kg·K), specific heat of TPU (1.7–1.9 kJ/(kg·K))
K_FLOOR = 0.5  # the stiffness factor's lower bound


@dataclass(frozen=True)
class ThermalParams:
    """The named parameters of the model (module docstring)."""

    alpha_per_k: float
    tau_s: float
    heat_capacity_j_per_k: float
    heated_fraction: float = 1.0


@dataclass
class ThermalState:
    """ΔT of the beam (K) and its joints' cold stiffness; mutable (the scene snapshots ``vars`` of it)."""

    params: ThermalParams
    joints: np.ndarray  # joint ids scaled
    k0: np.ndarray  # their cold stiffness (N·m/rad)
    rise_k: float = 0.0
    heat_j: float = 0.0  # energy that heated the beam so far (η·∫P dt)

    @property
    def factor(self) -> float:
        """k/k₀ now."""
        return max(1.0 - self.params.alpha_per_k * self.rise_k, K_FLOOR)

    def apply(self, model: Any) -> None:
        """Set the scaled joints' stiffness for the coming chunk."""
        model.jnt_stiffness[self.joints] = self.k0 * self.factor

    def heat(self, power_w: float, dt: float) -> None:
        """ΔT after ``dt`` seconds at a constant ``power_w`` into the beam (exact first-order step)."""
        p = self.params
        if dt <= 0 or not math.isfinite(power_w):
            return
        q = p.heated_fraction * max(power_w, 0.0)
        steady = q * p.tau_s / p.heat_capacity_j_per_k
        self.rise_k = steady + (self.rise_k - steady) * math.exp(-dt / p.tau_s)
        self.heat_j += q * dt

    def now(self) -> dict[str, float]:
        """The beam's state: temperature rise (K), stiffness factor k/k₀, heat taken in (J)."""
        return {"rise_k": self.rise_k, "stiffness_factor": self.factor, "heat_j": self.heat_j}

    def describe(self) -> dict[str, Any]:
        return {
            "model": "C dT/dt = eta P - C T/tau; k = k0 (1 - alpha T), per physics chunk",
            "alpha_per_k": self.params.alpha_per_k,
            "tau_s": self.params.tau_s,
            "heat_capacity_j_per_k": self.params.heat_capacity_j_per_k,
            "heated_fraction": self.params.heated_fraction,
            "joints": len(self.joints),
        }


def beam_joints(model: Any) -> np.ndarray:
    """Ids of the beam's hinge joints (named ``beam…``)."""
    ids = [
        i
        for i in range(model.njnt)
        if model.jnt_type[i] == mujoco.mjtJoint.mjJNT_HINGE
        and (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, i) or "").startswith("beam")
    ]
    return np.asarray(ids, dtype=int)


def thermal_state(model: Any, params: ThermalParams) -> ThermalState:
    """A cold beam (ΔT = 0) whose hinges in ``model`` the drift will scale."""
    joints = beam_joints(model)
    if not len(joints):
        raise ValueError("thermal drift: the model has no beam hinge joints to soften")
    return ThermalState(params, joints, model.jnt_stiffness[joints].copy())


def stage_power(t: np.ndarray, stage_x: np.ndarray, pull_x: np.ndarray) -> float:
    """Mean power (W) the stage puts into the beam: −(beam's force on the stage)·(stage velocity)."""
    if len(t) < 3:
        return 0.0
    v = np.gradient(stage_x, t)
    return float(np.mean(-pull_x * v))
