"""A first version of the paper's walker (Sec. IV-B), after the structure the planning prototype ran.

Body frame: x forward (away from the cart), y left, z up; the floor is z = 0. The body slides in x, y, z and
rolls/pitches (no yaw). On it: a 45 g plate, a 110 g motor whose rotor carries a 40 g mass at 10 mm
spinning in the x–z plane (f Hz = f turn/s), two PRB3 legs sticking out sideways and mirrored across the
sagittal plane (left −φ, right +φ) with a 66.5 mm rigid foot and a 3 mm sphere sole each, and a 100 g cart
rigidly at the tail on two frictionless wheels (total length 295 mm).

Spin sense and leg chirality are guesses (the paper does not give them); this combination walks backward
at 23 Hz and forward above ~27 Hz like the paper, but slower (≈ −10 mm/s at 23 Hz, +14 at 65 Hz, peak
≈ +30 at 40 Hz vs the paper's −35.7 and +156.3), and the result holds within ~5 mm/s for contact time
constants 1 → 0.25 ms (dt 1e-4 → 2.5e-5).

Simplifications to refine later: contact time constant 1 ms at dt = 1e-4 (the planning prototype
converged only near 0.25 ms at dt 2.5e-5, and the walking speed's sign depends on it), unknown motor
orientation/radius/friction as guessed in the planning notes. There is no load-cell plate under the walker:
``force_nt`` is zero, so the load-cell stream carries tare + noise only.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import mujoco
import numpy as np

from beambench.sim.beam import BeamModel, add_beam
from beambench.sim.drive import KinematicServo, VelocityRamp
from beambench.sim.engine import INTEGRATORS, DrivenScene, Physics
from beambench.streams import WALKER_MARKERS


@dataclass(frozen=True)
class WalkerParams:
    """Walker constants (SI); guessed where the paper is silent (see the planning notes)."""

    plate_mass: float = 0.045
    motor_mass: float = 0.110
    eccentric_mass: float = 0.040
    eccentric_radius: float = 0.010
    rotor_inertia: float = 1.35e-5  # kg·m² (Maxon EC45 flat class)
    cart_mass: float = 0.100
    length: float = 0.295  # m, plate front to cart tail
    leg_offset: float = 0.03  # m, clamp distance from the centre line
    foot_length: float = 0.0665
    foot_mass: float = 0.020
    sole_radius: float = 0.003
    wheel_radius: float = 0.008
    friction: float = 0.5
    contact_timeconst: float = 0.001
    contact_dampratio: float = 1.0
    servo_hz: float = 300.0  # rotor angle servo bandwidth
    vel_ramp_rate: float = 50.0  # turn/s²
    spin: float = -1.0  # rotor turns about -y (guess; with the legs below it walks backward at 23 Hz, forward above ~27 Hz)
    left_chirality: float = -1.0  # left leg twisted -φ, right leg +φ (mirror images)
    torque_constant: float = 0.0255  # N·m/A
    bus_voltage: float = 24.0
    preroll_s: float = 0.5
    timestep: float = 1e-4

    @classmethod
    def with_overrides(cls, overrides: dict[str, Any]) -> "WalkerParams":
        known = {f.name for f in fields(cls)}
        return cls(**{k: float(v) for k, v in overrides.items() if k in known})


def build_walker_spec(beam: BeamModel, twist_deg: float, wp: WalkerParams, integrator: str = "implicitfast",
                      timestep: float = 1e-4) -> mujoco.MjSpec:
    """The walker scene as an ``MjSpec``."""
    spec = mujoco.MjSpec()
    spec.modelname = "beambench_walker"
    spec.option.timestep = timestep
    spec.option.integrator = INTEGRATORS[integrator]
    solref = [wp.contact_timeconst, wp.contact_dampratio]
    friction = [wp.friction, 0.005, 0.0001]
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.01], solref=solref,
                            friction=friction, rgba=[0.8, 0.8, 0.8, 1])

    z0 = wp.foot_length + 0.002  # clamp height: feet just above the floor before settling
    body = spec.worldbody.add_body(name="walker", pos=[0, 0, z0])
    hinge, slide = mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE
    for name, jtype, axis in (("x", slide, [1, 0, 0]), ("y", slide, [0, 1, 0]), ("z", slide, [0, 0, 1]),
                              ("roll", hinge, [1, 0, 0]), ("pitch", hinge, [0, 1, 0])):
        body.add_joint(name=name, type=jtype, axis=axis)
    front = 0.04
    body.add_geom(name="plate", type=mujoco.mjtGeom.mjGEOM_BOX, size=[front, 0.03, 0.0015], mass=wp.plate_mass,
                  contype=0, conaffinity=0, rgba=[0.3, 0.3, 0.3, 1])
    body.add_geom(name="motor", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.022, 0.007, 0], pos=[0, 0, 0.01],
                  quat=[math.cos(math.pi / 4), math.sin(math.pi / 4), 0, 0], mass=wp.motor_mass, contype=0,
                  conaffinity=0, rgba=[0.2, 0.2, 0.2, 1])
    body.add_site(name="body", pos=[0, 0, 0], size=[0.003, 0, 0])
    rotor = body.add_body(name="rotor", pos=[0, 0, 0.01])
    rotor.add_joint(name="rotor", type=hinge, axis=[0, 1, 0], armature=wp.rotor_inertia)
    rotor.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.006, 0, 0], pos=[wp.eccentric_radius, 0, 0],
                   mass=wp.eccentric_mass, contype=0, conaffinity=0, rgba=[0.8, 0.1, 0.1, 1])
    # cart rigidly at the tail, on two frictionless wheels
    tail = front - wp.length
    cart_x = tail + 0.02
    wheel_z = -(z0 - wp.wheel_radius)
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[-front, 0, 0, cart_x, 0, 0], size=[0.003, 0, 0],
                  mass=0.0, contype=0, conaffinity=0)
    body.add_geom(name="cart", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.02, 0.03, 0.01], pos=[cart_x, 0, 0],
                  mass=wp.cart_mass, contype=0, conaffinity=0, rgba=[0.5, 0.4, 0.3, 1])
    for side in (1, -1):
        body.add_geom(name=f"wheel_{'l' if side > 0 else 'r'}", type=mujoco.mjtGeom.mjGEOM_SPHERE,
                      size=[wp.wheel_radius, 0, 0], pos=[cart_x, side * 0.03, wheel_z], mass=0.0,
                      friction=[0, 0, 0], condim=1, priority=1, solref=solref)
    # legs: left along +y with +φ, right along −y (frame turned 180° about z) with −φ: mirror images
    for side, name in ((1, "left"), (-1, "right")):
        quat = [1, 0, 0, 0] if side > 0 else [0, 0, 0, 1]
        sites = add_beam(body, beam, side * wp.left_chirality * twist_deg, pos=[0, side * wp.leg_offset, 0], quat=quat,
                         prefix=f"{name}_")
        tip = spec.body(sites.tip_body)
        r = wp.sole_radius
        tip.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0, 0, 0, 0, 0, -(wp.foot_length - 2 * r)],
                     size=[0.002, 0, 0], mass=0.0, contype=0, conaffinity=0, rgba=[0.9, 0.5, 0.1, 1])
        tip.add_geom(name=f"sole_{name}", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[r, 0, 0],
                     pos=[0, 0, -(wp.foot_length - r)], mass=wp.foot_mass, priority=1, solref=solref,
                     friction=friction, condim=3)
        tip.add_site(name=f"foot_{name}", pos=[0, 0, -wp.foot_length], size=[0.002, 0, 0])
    spec.add_actuator(name="rotor_servo", target="rotor", trntype=mujoco.mjtTrn.mjTRN_JOINT,
                      gaintype=mujoco.mjtGain.mjGAIN_FIXED, biastype=mujoco.mjtBias.mjBIAS_AFFINE)
    site = mujoco.mjtObj.mjOBJ_SITE
    for marker in WALKER_MARKERS:
        spec.add_sensor(name=marker, type=mujoco.mjtSensor.mjSENS_FRAMEPOS, objtype=site, objname=marker)
    spec.add_sensor(name="rotor_torque", type=mujoco.mjtSensor.mjSENS_ACTUATORFRC,
                    objtype=mujoco.mjtObj.mjOBJ_ACTUATOR, objname="rotor_servo")
    return spec


class WalkerSim(DrivenScene):
    """The walker advanced in chunks; channels: ``markers`` [n, 3, 3] (body, foot_left, foot_right),
    ``force_nt`` (zeros: no load-cell plate), the motor's ``theta``/``omega``/``setpoint`` and ``rotor_torque``."""

    markers = WALKER_MARKERS

    def __init__(self, beam: BeamModel, twist_deg: float = 90.0, params: WalkerParams | None = None,
                 integrator: str = "implicitfast", timestep: float | None = None) -> None:
        self.beam, self.twist_deg = beam, twist_deg
        self.rig = params or WalkerParams.with_overrides(beam.params.rig)
        self.integrator = integrator
        h = timestep or self.rig.timestep
        self.spec = build_walker_spec(beam, twist_deg, self.rig, integrator, h)
        model = self.spec.compile()
        super().__init__(Physics(model))
        self.ramp = VelocityRamp(self.rig.vel_ramp_rate)
        inertia = self.rig.rotor_inertia + self.rig.eccentric_mass * self.rig.eccentric_radius**2
        self.servo = KinematicServo(model, "rotor_servo", inertia, self.rig.servo_hz, integrator, h)
        self.physics.reset_to_equilibrium(self.rig.preroll_s, np.zeros(1))

    def set_frequency(self, hz: float) -> None:
        self.ramp.setpoint = float(hz)

    def _plan(self, n: int, h: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        omega, theta = self.ramp.plan(n, h)
        ctrl, _ = self.servo.controls(self.rig.spin * theta, h)
        motor = {"theta": theta[:-1], "omega": omega[:-1], "setpoint": np.full(n, self.ramp.setpoint)}
        return ctrl[:, None], motor

    def _channels(self, sens: np.ndarray) -> dict[str, np.ndarray]:
        n = len(sens)
        markers = np.stack([self.sensor(sens, m) for m in WALKER_MARKERS], axis=1)
        return {"markers": markers, "force_nt": np.zeros((n, 2)), "rotor_torque": self.sensor(sens, "rotor_torque")[:, 0]}

    def motor_torque(self, channels: dict[str, np.ndarray]) -> np.ndarray:
        return self.rig.spin * channels["rotor_torque"]

    def identity(self) -> dict[str, Any]:
        m = self.physics.model
        return {
            "scene": "walker",
            **self.beam.describe(),
            "twist_deg": self.twist_deg,
            "walker_params": asdict(self.rig),
            "integrator": self.integrator,
            "timestep": self.physics.timestep,
            "timestep_policy": "fixed",
            "nq": int(m.nq),
            "nv": int(m.nv),
            "mass_kg": float(m.body_subtreemass[m.body("walker").id]),
            "mujoco_version": mujoco.__version__,
        }
