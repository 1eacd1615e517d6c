"""The paper's walker (Sec. IV-B): a plate with a motor spinning a 40 g offset mass, two mirrored twisted-beam legs.

Body frame: x forward (away from the cart), y left, z up; the floor is z = 0. The body slides in x and z
and rolls/pitches. The paper's slider holds the robot "along the x-axis and about the yaw axis" while
"roll, pitch, z-axis and y-axis" are free; since the robot walks, the paper's y is the walking direction
and its x the lateral one, so here lateral translation and yaw are locked (``lateral_free = 1`` frees the
lateral slide, e.g. for the mirror-symmetry check). On the body: a carbon plate, a Maxon EC 45 flat (Ø42.9 mm)
lying on its side with its axis along y above the leg clamps, its rotor carrying the 40 g offset mass at
``eccentric_radius`` turning in the x–z plane (f Hz = f turn/s); two legs (any beam model: the physical twin's
segmented rod, or PRB3) leaving the plate sideways, mirrored across the sagittal plane (left −φ, right +φ),
each clamped with ``leg_roll_deg`` about its axis (0: width vertical), raked by ``leg_mount_deg``, with a rigid
foot of ``foot_length`` hanging from its tip to a sphere sole carrying ``foot_mass``; a 100 g cart rigidly at the
tail on two frictionless wheels, which carry their share of the weight by the moment balance (total length
295 mm). Every number's source: the comments of :class:`WalkerParams`; the physical set's walker block
(``sim_backend/rod_physical.yaml``) with its bounds; docs/walker-twin.md for the model, the evidence and the
numerics.

The class defaults are the effective PRB3 walker (``sim.model: prb3, sim.params: paper``; 3 g feet, friction 0.5,
fitted to the paper's two speeds on PRB3 legs whose twist springs are ~3x the anchored strip's): −38 / +161 mm/s
at 23 / 65 Hz, steady; ``paper_guesses`` is the same robot with the paper's 20 g foot load.

There is no load-cell plate under the walker: ``force_nt`` is zero, so the load-cell stream carries
tare + noise only.
"""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any

import mujoco
import numpy as np

from beambench.acquisition.protocol.scenes import WALKER
from beambench.acquisition.streams import WALKER_MARKERS
from beambench.common.errors import BeambenchError
from beambench.common.yaml_config import ConfigError
from beambench.sim.engine.stepping import INTEGRATORS, Physics
from beambench.sim.models.beam import BeamModel, add_beam, qinv, qmul, quat_x, quat_y
from beambench.sim.models.families import FAMILIES
from beambench.sim.models.hysteretic import HystereticDamping
from beambench.sim.models.registry import UnknownModelError, family_of
from beambench.sim.scene_params import WalkerParams
from beambench.sim.scenes.drive import DrivenScene, KinematicServo, VelocityRamp
from beambench.sim.scenes.registry import SceneConfig, register


class WalkerLegError(BeambenchError, ValueError):
    """A leg model the walker refuses (one line); ``reason`` without the model name."""

    def __init__(self, name: str, reason: str) -> None:
        self.name, self.reason = name, reason
        super().__init__(f"sim.model = {name!r}: {reason}")


def check_leg_model(name: str) -> None:
    """Refuse leg models of a family the walker cannot build (its ``walker_leg`` flag; every shipped family builds:
    PRB3 and the segmented rods; the shipped walker stands on the contact rig's physical rod, docs/walker-twin.md)."""
    try:
        family = family_of(name)
    except UnknownModelError as exc:
        raise WalkerLegError(name, str(exc).split(": ", 1)[-1]) from None
    if not family.walker_leg:
        legs = " or ".join(f.name for f in FAMILIES.values() if f.walker_leg)
        raise WalkerLegError(name, f"refused for the walker: use a leg model of {legs}")


# PGS, not Newton: at most 10 constraint rows (two pyramidal soles, two wheels) against 35 dofs, so Newton's dense
# 35 x 35 Hessian per step costs more than PGS's 2-14 sweeps; the steady speeds agree within 0.6 mm/s at 5-80 Hz and
# the step costs a quarter less CPU (docs/performance.md, "Walker sweep speed")
SOLVER = mujoco.mjtSolver.mjSOL_PGS

WALKER_FRONT = 0.04  # m, the plate's front edge ahead of the leg clamps (the platform's length is counted from it)


def build_walker_spec(
    beam: BeamModel, twist_deg: float, wp: WalkerParams, integrator: str = "implicitfast", timestep: float = 1e-4
) -> mujoco.MjSpec:
    """The walker scene as an ``MjSpec``. Only the soles and the wheels touch the floor, through explicit
    ``<pair>``s (every geom has contype = conaffinity = 0: no broad phase); no force sensor (it would add a
    post-constraint RNE pass); the constraint solver is :data:`SOLVER` with islands off."""
    spec = mujoco.MjSpec()
    spec.modelname = "beambench_walker"
    spec.option.timestep = timestep
    spec.option.integrator = INTEGRATORS[integrator]
    spec.option.solver = SOLVER
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_ISLAND  # one kinematic tree: islands find nothing
    solref = [wp.contact_timeconst, wp.contact_dampratio]
    friction = [wp.friction, 0.005, 0.0001]  # the floor's own (visual: contacts come from the pairs below)
    spec.worldbody.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[2, 2, 0.01],
        solref=solref,
        friction=friction,
        contype=0,
        conaffinity=0,
        rgba=[0.8, 0.8, 0.8, 1],
    )
    droop = math.radians(wp.leg_droop_deg)
    z0 = beam.params.length * math.sin(droop) + wp.foot_length + 0.002  # clamp height: soles just above the floor
    body = _add_body(spec, wp, z0)
    _add_cart(spec, body, wp, z0, solref)
    # legs: left along +y with +φ, right along −y (frame turned 180° about z) with −φ: mirror images; each
    # drooped by leg_droop_deg about the body's x axis (toward −z), its foot hanging along the raked vertical
    mount = quat_y(math.radians(wp.leg_mount_deg))
    foot_world = np.empty(3)
    mujoco.mju_rotVecQuat(foot_world, np.array([0.0, 0, -1]), mount)
    for side, name, chir in ((1, "left", wp.left_chirality), (-1, "right", wp.right_chirality)):
        quat = qmul(quat_x(-side * droop), mount)
        if side < 0:
            quat = qmul(quat, [0.0, 0, 0, 1])
        quat = qmul(quat, quat_y(side * math.radians(wp.leg_roll_deg)))  # mirrored: the same turn seen from outside
        sites = add_beam(
            body, beam, chir * twist_deg, pos=[0, side * wp.leg_offset, 0], quat=quat.tolist(), prefix=f"{name}_"
        )
        down = np.empty(3)
        mujoco.mju_rotVecQuat(down, foot_world, qinv(quat))
        _add_foot(spec, spec.body(sites.tip_body), name, wp, solref, down)
    spec.add_actuator(
        name="rotor_servo",
        target="rotor",
        trntype=mujoco.mjtTrn.mjTRN_JOINT,
        gaintype=mujoco.mjtGain.mjGAIN_FIXED,
        biastype=mujoco.mjtBias.mjBIAS_AFFINE,
    )
    site = mujoco.mjtObj.mjOBJ_SITE
    for marker in WALKER_MARKERS:
        spec.add_sensor(name=marker, type=mujoco.mjtSensor.mjSENS_FRAMEPOS, objtype=site, objname=marker)
    spec.add_sensor(
        name="rotor_torque",
        type=mujoco.mjtSensor.mjSENS_ACTUATORFRC,
        objtype=mujoco.mjtObj.mjOBJ_ACTUATOR,
        objname="rotor_servo",
    )
    return spec


def _add_body(spec: mujoco.MjSpec, wp: WalkerParams, z0: float) -> mujoco.MjsBody:
    """The walker's body at clamp height ``z0`` on its slides and hinges: the plate, the motor and the rotor
    carrying the offset mass."""
    body = spec.worldbody.add_body(name="walker", pos=[0, 0, z0])
    hinge, slide = mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE
    dofs = [
        ("x", slide, [1, 0, 0]),
        ("y", slide, [0, 1, 0]),
        ("z", slide, [0, 0, 1]),
        ("roll", hinge, [1, 0, 0]),
        ("pitch", hinge, [0, 1, 0]),
    ]
    for name, jtype, axis in dofs:
        if name != "y" or wp.lateral_free:
            body.add_joint(name=name, type=jtype, axis=axis)
    invisible = dict(contype=0, conaffinity=0)
    body.add_geom(
        name="plate",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[WALKER_FRONT, 0.03, 0.0015],
        mass=wp.plate_mass,
        rgba=[0.3, 0.3, 0.3, 1],
        **invisible,
    )
    body.add_geom(
        name="motor",
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[wp.motor_radius, 0.007, 0],
        pos=[wp.motor_x, 0, wp.rotor_height],
        quat=_motor_quat(wp.motor_flat),
        mass=wp.motor_mass,
        rgba=[0.2, 0.2, 0.2, 1],
        **invisible,
    )
    body.add_site(name="body", pos=[0, 0, 0], size=[0.003, 0, 0])
    rotor = body.add_body(name="rotor", pos=[wp.motor_x, 0, wp.rotor_height])
    axis = [1, 0, 0] if wp.motor_flat == 2 else [0, 0, 1] if wp.motor_flat else [0, 1, 0]
    rotor.add_joint(name="rotor", type=hinge, axis=axis, armature=wp.rotor_inertia)
    rotor.add_geom(
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[0.006, 0, 0],
        pos=[0, 0, wp.eccentric_radius] if wp.motor_flat == 2 else [wp.eccentric_radius, 0, 0],
        mass=wp.eccentric_mass,
        rgba=[0.8, 0.1, 0.1, 1],
        **invisible,
    )
    return body


def _motor_quat(motor_flat: float) -> list[float]:
    """The motor cylinder's orientation (its axis = the rotor's): along y (0), z (1) or x (2)."""
    c = math.cos(math.pi / 4)
    return [1.0, 0, 0, 0] if motor_flat == 1 else [c, 0, c, 0] if motor_flat == 2 else [c, c, 0, 0]


def _add_cart(spec: mujoco.MjSpec, body: mujoco.MjsBody, wp: WalkerParams, z0: float, solref: list) -> None:
    """The cart rigidly at the tail (its boom from the plate) on two frictionless wheels."""
    invisible = dict(contype=0, conaffinity=0)
    cart_x = WALKER_FRONT - wp.length + 0.02
    wheel_z = -(z0 - wp.wheel_radius)
    body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        fromto=[-WALKER_FRONT, 0, 0, cart_x, 0, 0],
        size=[0.003, 0, 0],
        mass=wp.frame_mass,
        **invisible,
    )
    body.add_geom(
        name="cart",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.02, 0.03, 0.01],
        pos=[cart_x, 0, 0],
        mass=wp.cart_mass,
        rgba=[0.5, 0.4, 0.3, 1],
        **invisible,
    )
    for side in (1, -1):
        wheel = f"wheel_{'l' if side > 0 else 'r'}"
        body.add_geom(
            name=wheel,
            type=mujoco.mjtGeom.mjGEOM_SPHERE,
            size=[wp.wheel_radius, 0, 0],
            pos=[cart_x, side * 0.03, wheel_z],
            mass=0.0,
            rgba=[0.1, 0.1, 0.1, 1],
            **invisible,
        )
        # explicit pairs only (no broad phase): frictionless wheel on the floor
        spec.add_pair(geomname1="floor", geomname2=wheel, condim=1, solref=solref)


def _add_foot(
    spec: mujoco.MjSpec, tip: mujoco.MjsBody, name: str, wp: WalkerParams, solref: list, down: np.ndarray
) -> None:
    """A rigid foot on a leg's tip body along ``down`` (a unit vector in the tip frame): the bar, the sole with
    its mass, its floor pair and the foot marker."""
    r = wp.sole_radius
    tip.add_geom(
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        fromto=[0, 0, 0, *(down * (wp.foot_length - 2 * r))],
        size=[0.002, 0, 0],
        mass=wp.foot_bar_mass,
        contype=0,
        conaffinity=0,
        rgba=[0.9, 0.5, 0.1, 1],
    )
    tip.add_geom(
        name=f"sole_{name}",
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[r, 0, 0],
        pos=(down * (wp.foot_length - r)).tolist(),
        mass=wp.foot_mass,
        contype=0,
        conaffinity=0,
    )
    spec.add_pair(
        geomname1="floor",
        geomname2=f"sole_{name}",
        condim=3 if wp.friction > 0 else 1,  # frictionless: normal-only (μ = 0 in a cone diverges)
        solref=solref,
        friction=[wp.friction, wp.friction, 0.005, 0.0001, 0.0001],
    )
    tip.add_site(name=f"foot_{name}", pos=(down * wp.foot_length).tolist(), size=[0.002, 0, 0])


FOLD_DROOP_DEG = 45.0  # legs closer to sideways than this carry the sole's push on their torsion


def sole_load(model: mujoco.MjModel) -> float:
    """Static load per sole (N) of the walker in its natural shape: the soles' share of the weight by the moment
    balance about the wheels' line (pitch axis), halved."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    body = model.body("walker").id
    weight = float(model.body_subtreemass[body]) * -float(model.opt.gravity[2])
    x_com, x_wheel = float(data.subtree_com[body][0]), float(data.geom("wheel_l").xpos[0])
    x_sole = 0.5 * float(data.geom("sole_left").xpos[0] + data.geom("sole_right").xpos[0])
    return 0.5 * weight * (x_com - x_wheel) / (x_sole - x_wheel)


def leg_fold(model: mujoco.MjModel, beam: BeamModel, wp: WalkerParams) -> str | None:
    """A sentence when the legs cannot carry the walker, else None: a sole pushed up by the floor a foot length
    below a sideways leg's tip is an inverted pendulum on the leg's twist stiffness k, standing only while its
    load F · foot length < k (``tests/test_walker_leg_statics.py``; docs/walker-twin.md)."""
    if wp.leg_droop_deg >= FOLD_DROOP_DEG or wp.foot_length <= 0:
        return None
    k = beam.torsion_stiffness()
    load, limit = sole_load(model), k / wp.foot_length
    if load <= limit:
        return None
    return (
        f"the walker's {beam.name} legs fold: each sole carries {load:.2f} N, {load / limit:.1f}x the {limit:.2f} N "
        f"that a {1e3 * wp.foot_length:g} mm foot stands on the legs' twist stiffness ({k:.3g} N·m/rad), so its "
        "speeds are no walking robot's (docs/walker-twin.md)"
    )


QUENCH_S = 0.001  # s, velocity-quench interval of the damped preroll


class WalkerSim(DrivenScene):
    """The walker advanced in chunks; channels: ``markers`` [n, 3, 3] (body, foot_left, foot_right),
    ``force_nt`` (zeros: no load-cell plate), the motor's ``theta``/``omega``/``setpoint`` and ``rotor_torque``."""

    rig: WalkerParams

    markers = WALKER_MARKERS

    def __init__(
        self,
        beam: BeamModel,
        twist_deg: float = 90.0,
        params: WalkerParams | None = None,
        integrator: str = "implicitfast",
        timestep: float | None = None,
    ) -> None:
        check_leg_model(beam.name)
        self.beam, self.twist_deg = beam, twist_deg
        self.rig = params or WalkerParams.with_overrides(beam.params.walker or beam.params.rig)
        self.integrator = integrator
        h = timestep or self.rig.timestep
        self.spec = build_walker_spec(beam, twist_deg, self.rig, integrator, h)
        model = self.spec.compile()
        super().__init__(Physics(model))
        self.ramp = VelocityRamp(self.rig.vel_ramp_rate)
        inertia = self.rig.rotor_inertia + self.rig.eccentric_mass * self.rig.eccentric_radius**2
        self.servo = KinematicServo(model, "rotor_servo", inertia, self.rig.servo_hz, integrator, h)
        # beam.loss_factor > 0: the legs' dampers follow the drive frequency (sim.models.hysteretic), not beta
        loss = float(beam.params.loss_factor)
        self.damping = HystereticDamping.of(model, loss) if loss > 0 else None
        if self.damping is not None:
            self.damping.at(model, 0.0)
        self._preroll()

    def _preroll(self) -> None:
        """Motor off, settle under gravity: half of ``preroll_s`` quenched (velocities zeroed every
        ``QUENCH_S``, which removes the light foot's ringing on the stiff contact), then the other half free, into
        the steady creep of the soft contacts; time is then set to zero."""
        ph = self.physics
        quench = max(1, round(QUENCH_S / ph.timestep))
        ctrl = np.zeros((quench, 1))
        ph.data.ctrl[:] = 0.0
        for _ in range(round(0.5 * self.rig.preroll_s / QUENCH_S)):
            ph.step(ctrl)
            ph.data.qvel[:] = 0.0
        ph.step(np.zeros((round(0.5 * self.rig.preroll_s / ph.timestep), 1)))
        # keep the velocities: the soft friction cone holds the splayed legs' sideways push only while the soles
        # creep (~1e-5 m/s), so zeroing them would leave the legs out of balance (weight carried -2 %, 3 g foot)
        ph.data.time = 0.0
        mujoco.mj_forward(ph.model, ph.data)

    def set_frequency(self, hz: float) -> None:
        self.ramp.setpoint = float(hz)
        if self.damping is not None:
            self.damping.at(self.physics.model, hz)

    def model_warnings(self) -> list[str]:
        """What makes this walker no robot (``WarnsOfModel``): legs whose feet fold under it (:func:`leg_fold`)."""
        fold = leg_fold(self.physics.model, self.beam, self.rig)
        return [fold] if fold else []

    @staticmethod
    def step_cost(hz: float) -> float:
        """The physics' relative cost per simulated second at drive frequency ``hz``: the sim rig cuts a sweep into
        segments of equal cost with it (:func:`beambench.backends.lookahead.cut_points`). With PGS at dt 1.2e-4 on a loaded
        machine: ~14.5 µs/step at 1–20 Hz, ~13.3 at 21–37 Hz, ~11 from 40 Hz (Newton: ~20, ~17.5, ~12.5); the shipped
        sweep is cut at 37 Hz, its two workers then within ~10 % of each other's CPU time (docs/performance.md)."""
        return float(np.interp(hz, [0, 3, 4, 12, 20, 33, 45, 55], [1.0, 1.1, 1.45, 1.4, 1.3, 1.25, 1.1, 1.0]))

    def _plan(self, n: int, h: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        omega, theta = self.ramp.plan(n, h)
        ctrl, _ = self.servo.controls(self.rig.spin * theta, h)
        motor = {"theta": theta[:-1], "omega": omega[:-1], "setpoint": np.full(n, self.ramp.setpoint)}
        return ctrl[:, None], motor

    def _channels(self, sens: np.ndarray) -> dict[str, np.ndarray]:
        n = len(sens)
        markers = np.stack([self.sensor(sens, m) for m in WALKER_MARKERS], axis=1)
        return {
            "markers": markers,
            "force_nt": np.zeros((n, 2)),
            "rotor_torque": self.sensor(sens, "rotor_torque")[:, 0],
        }

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


def measure_speed(
    beam: BeamModel,
    frequency_hz: float,
    params: WalkerParams | None = None,
    twist_deg: float = 90.0,
    settle_s: float = 1.0,
    record_s: float = 1.5,
    timestep: float | None = None,
) -> tuple[float, float]:
    """Body speed (forward, lateral; m/s) at ``frequency_hz``: the motor ramps up from rest, the walker settles
    for ``settle_s`` after the ramp, then a least-squares slope of the body marker over ``record_s``."""
    sim = WalkerSim(beam, twist_deg, params, timestep=timestep)
    try:
        sim.set_frequency(frequency_hz)
        t_on = frequency_hz / sim.rig.vel_ramp_rate + settle_s
        tr = sim.advance_to(t_on + record_s)
    finally:
        sim.physics.close()
    sel = tr.t >= t_on
    body = tr.channels["markers"][sel, 0]
    vx, vy = (float(np.polyfit(tr.t[sel], body[:, k], 1)[0]) for k in (0, 1))
    return vx, vy


# --- scene registration (beambench.sim.scenes.registry) --------------------------------------------------------
@register(WALKER)
def build(cfg: SceneConfig) -> WalkerSim:
    """The walker of a protocol; a leg model it cannot stand on is a ConfigError (one line)."""
    sim = cfg.sim
    try:
        return WalkerSim(cfg.beam, twist_deg=sim.settings.twist_deg, integrator=sim.integrator, timestep=sim.timestep)
    except WalkerLegError as exc:
        raise ConfigError("<protocol>", "sim.model", exc.name, exc.reason) from None
