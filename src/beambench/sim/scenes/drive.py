"""The motor as the ODrive runs it in velocity-ramp mode: the speed moves toward the setpoint at a fixed
ramp rate (``controller.config.vel_ramp_rate``, turn/s²) and the crank angle integrates the speed.

f Hz of drive means f turn/s of crank. ``plan`` returns the speed and angle at the next ``n + 1`` physics
row times (the current one included), so a scene can precompute a whole chunk of stage references.
"""

from __future__ import annotations

import math

import numpy as np


class VelocityRamp:
    """Crank speed ω (turn/s) ramping toward ``setpoint`` at ``rate`` turn/s², angle θ (rad)."""

    def __init__(self, rate: float) -> None:
        if rate <= 0:
            raise ValueError("ramp rate must be > 0")
        self.rate = rate
        self.setpoint = 0.0
        self.omega = 0.0
        self.theta = 0.0

    def plan(self, n: int, h: float) -> tuple[np.ndarray, np.ndarray]:
        """ω and θ at steps 0..n (n + 1 values); the state advances to step n."""
        k = np.arange(n + 1)
        delta = self.setpoint - self.omega
        omega = self.omega + math.copysign(1.0, delta) * np.minimum(k * self.rate * h, abs(delta))
        theta = np.empty(n + 1)
        theta[0] = self.theta
        np.cumsum(math.pi * h * (omega[:-1] + omega[1:]), out=theta[1:])
        theta[1:] += self.theta
        self.omega, self.theta = float(omega[-1]), float(theta[-1])
        return omega, theta


class KinematicServo:
    """Makes a joint follow a planned reference exactly: a PD servo (general actuator, affine bias) with a
    feed-forward that uses the *discrete* acceleration the integrator will realise.

    For semi-implicit Euler (implicit velocity damping): M·(v⁺ − v)/h = kp·(u − x) − kv·v⁺, so with
    x, v on the reference and v⁺ = (r₊ − r)/h the control is u = r + (M·a + kv·v⁺)/kp. (A continuous
    acceleration instead gives ~3 % amplitude error.) The feedback only absorbs the load's reaction.
    """

    def __init__(self, model, actuator: str, inertia: float, bandwidth_hz: float, integrator: str, h0: float) -> None:
        wn = 2 * math.pi * bandwidth_hz
        self.m, self.kp, self.kv = inertia, inertia * wn**2, 2 * inertia * wn
        act = model.actuator(actuator).id
        model.actuator_gainprm[act, 0] = self.kp
        model.actuator_biasprm[act, :3] = [0.0, -self.kp, -self.kv]
        self.implicit = integrator in ("implicitfast", "implicit", "discrete")
        self.r_prev: float | None = None
        self.h_prev = h0

    def controls(self, ref: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
        """Controls for steps 0..n-1 from the reference at rows 0..n; also the planned acceleration."""
        r_prev = ref[0] if self.r_prev is None else self.r_prev
        w = np.diff(ref) / h  # velocity over each step
        v = np.empty_like(w)
        v[0] = (ref[0] - r_prev) / self.h_prev
        v[1:] = w[:-1]
        acc = (w - v) / h
        ctrl = ref[:-1] + (self.m * acc + self.kv * (w if self.implicit else v)) / self.kp
        self.r_prev, self.h_prev = float(ref[-2]), h
        return ctrl, acc
