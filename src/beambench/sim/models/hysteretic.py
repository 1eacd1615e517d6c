"""Material damping with a frequency-independent loss factor η (``beam.loss_factor``), as an equivalent viscous
damping chosen at the drive frequency.

A solid's internal friction dissipates per cycle a fixed fraction of the strain energy whatever the rate
(hysteretic, "rate-independent" damping: a complex stiffness k(1 + iη); TPU's tan δ ≈ 0.05–0.2 over 1–50 Hz).
MuJoCo integrates viscous dampers only, so each hinge gets the viscous coefficient that dissipates the same energy
per cycle of harmonic motion at the drive's angular frequency ω: π·η·k·u² = π·c·ω·u², c = η·k/ω (Chopra,
*Dynamics of Structures*, §3.10, "rate-independent damping"; Clough & Penzien §3-8). It is exact for the forced
response at the drive frequency, which is the motion the contact rig's landmarks come from; a free mode of
frequency ω_n gets ζ = η·ω_n/(2ω) instead of η/2 (lighter below the drive, heavier above it). The coefficient is
reset at every new drive frequency (:meth:`HystereticDamping.at`). The alternative, stiffness-proportional β
(``beam.beta``, b = β·k), gives ζ = β·ω/2: the release fit's 8.7 ms makes the free beam's first mode (34 Hz)
ζ 0.94, ten times the material's; a Rayleigh pair (α·M + β·K) would need mass-proportional dampers that MuJoCo's
joint damping cannot express.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

MIN_DRIVE_HZ = 1.0  # below this (the motor at rest, a ramp from 0) the coefficient is that of 1 Hz


@dataclass
class HystereticDamping:
    """The beam's hinges (``dofs``, their spring ``stiffness``) and the loss factor that sets their dampers."""

    dofs: np.ndarray
    stiffness: np.ndarray
    loss_factor: float

    @classmethod
    def of(cls, model: mujoco.MjModel, loss_factor: float) -> HystereticDamping:
        """The sprung hinges of ``model`` (the beam's: a scene's other joints carry no spring)."""
        hinge = mujoco.mjtJoint.mjJNT_HINGE
        joints = [j for j in range(model.njnt) if model.jnt_type[j] == hinge and model.jnt_stiffness[j] > 0]
        return cls(
            np.array([model.jnt_dofadr[j] for j in joints], int),
            np.array([model.jnt_stiffness[j] for j in joints], float),
            float(loss_factor),
        )

    def beta(self, hz: float) -> float:
        """The equivalent stiffness-proportional β (s) at drive frequency ``hz``: η/ω."""
        return self.loss_factor / (2 * math.pi * max(abs(hz), MIN_DRIVE_HZ))

    def at(self, model: mujoco.MjModel, hz: float) -> None:
        """Set the hinges' dampers for a drive at ``hz``: b = η·k/ω."""
        model.dof_damping[self.dofs] = self.beta(hz) * self.stiffness
