"""The drive of every scene: :class:`DrivenScene` (a scene whose controls are planned from the motor
command), the motor's :class:`VelocityRamp` and the :class:`KinematicServo` that makes the stage follow it.

The motor as the ODrive runs it in velocity-ramp mode: the speed moves toward the setpoint at a fixed
ramp rate (``controller.config.vel_ramp_rate``, turn/s²) and the crank angle integrates the speed.

f Hz of drive means f turn/s of crank. ``plan`` returns the speed and angle at the next ``n + 1`` physics
row times (the current one included), so a scene can precompute a whole chunk of stage references.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from beambench.sim.engine.stepping import Physics, Trajectory

if TYPE_CHECKING:
    from beambench.sim.models.hysteretic import HystereticDamping
    from beambench.sim.models.thermal import ThermalState


class MotorConstants(Protocol):
    """The electrics a simulated motor reports telemetry with (a scene's ``rig`` constants)."""

    @property
    def torque_constant(self) -> float: ...  # N·m/A

    @property
    def bus_voltage(self) -> float: ...  # V


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


@runtime_checkable
class CostsByFrequency(Protocol):
    """A scene whose physics costs more or less per simulated second with the drive frequency (the walker): the sim
    rig cuts a sweep into segments of equal cost, the dry run weighs its estimate."""

    def step_cost(self, hz: float) -> float: ...


@runtime_checkable
class ChecksCuts(Protocol):
    """A scene whose state forgets its past only where its regime is robust (the contact rig): the sim rig cuts a
    sweep into parallel segments only where a step run on from the carried state and the same step started from
    rest agree (:meth:`same_regime`), and otherwise moves the cut to a later step."""

    def same_regime(self, a: Trajectory, b: Trajectory, hz: float) -> bool: ...


@runtime_checkable
class WarmsUp(Protocol):
    """A scene whose beam may warm with the drive power (the contact rig's ``sim.thermal_drift``): its state, or
    None when the drift is off."""

    thermal: ThermalState | None


class DrivenScene:
    """A scene whose controls for a chunk are planned in advance from the motor command.

    The physics runs one step ahead of the clock: after ``advance_to(t)`` there are rows up to (at least)
    ``t``, so a device can sample any time ≤ ``t`` by interpolation without waiting for the next chunk.
    Subclasses implement :meth:`_plan` (controls + motor channels) and :meth:`_channels` (sensor → channels).
    """

    markers: tuple[str, ...] = ()  # the mocap markers' sensor names, in stream order
    rig: MotorConstants  # the scene's constants (RigParams, WalkerParams): the sim motor reads its electrics
    ramp: VelocityRamp  # the crank speed the motor command drives
    damping: HystereticDamping | None = None  # a loss-factor beam: its dampers follow the drive frequency

    def __init__(self, physics: Physics) -> None:
        self.physics = physics

    def advance_to(self, t_target: float) -> Trajectory:
        """Step until there is a row at time ≥ ``t_target``; returns the new rows."""
        h = self.physics.timestep
        n = int(np.ceil((t_target - self.physics.time) / h - 1e-9)) + 1
        if n <= 0:
            return Trajectory(np.zeros(0))
        ctrl, motor = self._plan(n, h)
        t, sens = self.physics.step(ctrl)
        channels = self._channels(sens)
        channels.update(motor)
        return Trajectory(t, channels)

    def snapshot(self) -> tuple:
        """State to undo a chunk computed ahead of time (physics, motor ramp, servo)."""
        extra = {
            name: dict(vars(getattr(self, name)))
            for name in ("ramp", "servo", "thermal")
            if getattr(self, name, None) is not None
        }
        return self.physics.snapshot(), extra

    def restore(self, snap: tuple) -> None:
        """Back to ``snap``, also on another copy of the scene (a segment's, computed elsewhere): the dampers of a
        loss-factor beam follow the restored setpoint, as :meth:`set_frequency` set them."""
        phys, extra = snap
        self.physics.restore(phys)
        for name, fields in extra.items():
            vars(getattr(self, name)).update(fields)  # in place: devices hold references to these objects
        if self.damping is not None:
            self.damping.at(self.physics.model, self.ramp.setpoint)

    def presettle(self, hz: float, seconds: float, t_phys: float) -> dict[str, np.ndarray]:
        """A later segment's start: from the current state ramp to ``hz``, settle ``seconds`` there, then continue
        on the run's time axis at ``t_phys``. Returns the last settled row's markers and motor angle (where the
        segment's rows are stitched on)."""
        self.set_frequency(hz)
        pre = self.advance_to(self.physics.time + hz / self.ramp.rate + seconds)
        row = {k: pre.channels[k][-1].copy() for k in ("markers", "theta")}
        self.physics.data.time = t_phys
        return row

    def set_frequency(self, hz: float) -> None:
        """A new crank-speed setpoint (turn/s), effective from the scene's current time."""
        raise NotImplementedError

    def motor_torque(self, channels: dict[str, np.ndarray]) -> np.ndarray:
        """The motor shaft torque (N·m) at each row of ``channels`` (the reaction of the drive)."""
        raise NotImplementedError

    def identity(self) -> dict[str, Any]:
        """What the scene is (model, parameters, timestep …) for the session's ``/general``."""
        raise NotImplementedError

    def _plan(self, n: int, h: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        raise NotImplementedError

    def _channels(self, sens: np.ndarray) -> dict[str, np.ndarray]:
        raise NotImplementedError

    def sensor(self, sens: np.ndarray, name: str) -> np.ndarray:
        return sens[:, self.physics.sensor_slices[name]]
