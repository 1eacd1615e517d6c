"""The single-beam contact rig (paper Sec. IV-A, Fig. 2j): a crank-driven stage, the beam, a rigid foot and
a plate below it. World frame: x = stage travel, y = along the beam (away from the stage), z = up; the
stage (beam clamp) is at the origin.

- Stage: a slider with a large armature driven by a servo whose feed-forward uses the *discrete*
  acceleration of the reference x = A·sin θ, so it follows the crank to ~µm whatever the beam does.
- Foot: rigid, ``foot_length`` below the beam tip in the natural shape, its mass at the sole (a sphere). With
  ``sole_at_corner`` it is the paper's load frame: a bar down from the tip and across to the frame's lower corner
  (``mass_dx``, ``mass_dy`` from the point below the tip), where the 20 g hangs and where the frame meets the plate.
- Plate: top at z = −(foot_length + gap); the gap is h' of the paper (5.5 mm; ``RigParams.plate_gap``, a
  parameter set's ``rig:`` block or the protocol's ``sim.plate_gap_mm`` may override it) measured from the
  foot's natural (unloaded, gravity-free) position, as the paper defines it ("the contact distance between the
  foot at its unload, natural position and the plate"): the scene is built in the natural shape and only
  then settles under gravity (``preroll_s``). Stiff contact: solref time constant ``contact_timeconst`` on the one
  sole–plate contact pair.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import mujoco
import numpy as np

from beambench.acquisition.protocol.scenes import CONTACT
from beambench.acquisition.streams import CONTACT_MARKERS
from beambench.sim.engine.stepping import INTEGRATORS, Physics, Trajectory
from beambench.sim.models.beam import BeamModel, add_beam
from beambench.sim.models.hysteretic import HystereticDamping
from beambench.sim.models.thermal import CP_TPU, ThermalParams, ThermalState, stage_power, thermal_state
from beambench.sim.scene_params import RigParams
from beambench.sim.scenes.drive import DrivenScene, KinematicServo, VelocityRamp
from beambench.sim.scenes.registry import SceneConfig, register

SOLIMP_D0, SOLIMP_DMAX = 0.9, 0.95  # MuJoCo's default contact impedance at zero and full penetration (solimp)
# The constraint solver. PGS solves the same regularised (soft-contact, pyramidal-cone) problem as Newton, to the
# same tolerance, 8–10 % cheaper a step here (one contact pair, 16 dof; bench_contact_step.py). Its trajectories part
# from Newton's only where the sweep is chaotic: the shipped sweep with PGS meets the convergence criterion against
# Newton at 2.5e-5 s (the same 18 labels from 23 Hz, contact fractions within 0.020 outside the lift-off band,
# tangential force within 1.4–5.3 % from 25 Hz; docs/performance.md, "One step").
SOLVER = mujoco.mjtSolver.mjSOL_PGS


def skip_unused_stages(model: mujoco.MjModel) -> None:
    """Disable the pipeline stages for what ``model`` has not got: constraint islands with one kinematic tree,
    equality, joint-limit and friction-loss rows, the mid-phase and parent filter with no broad-phase geoms (the
    contact is the explicit sole–plate pair), control clamping without control ranges. Same trajectory bit for
    bit, ~3 % less CPU a step (rod5g at 5e-5 s, 20 and 30 Hz; docs/performance.md, "One step")."""
    bits = mujoco.mjtDisableBit
    off = 0
    if model.ntree <= 1:
        off |= bits.mjDSBL_ISLAND
    if model.neq == 0:
        off |= bits.mjDSBL_EQUALITY
    if not model.jnt_limited.any():
        off |= bits.mjDSBL_LIMIT
    if not model.dof_frictionloss.any():
        off |= bits.mjDSBL_FRICTIONLOSS
    if not (model.geom_contype.any() or model.geom_conaffinity.any()):
        off |= bits.mjDSBL_MIDPHASE | bits.mjDSBL_FILTERPARENT
    if not model.actuator_ctrllimited.any():
        off |= bits.mjDSBL_CLAMPCTRL
    model.opt.disableflags |= int(off)


TIMESTEP_POLICY = ((40.0, 2e-4), (80.0, 1e-4), (float("inf"), 5e-5))  # (up to Hz, dt)


def default_timestep(frequency_hz: float, max_timestep: float = 0.0) -> float:
    """The timestep the contact rig needs at a drive frequency: foot path within 0.07 mm (below the mocap
    noise) of a dt = 2.5e-5 reference at a 1 mm gap up to 40 Hz; 1e-4 up to 80 Hz (planning notes); at most
    ``max_timestep`` (a twin's :attr:`RigParams.max_timestep`) when that is > 0."""
    return capped(next(dt for f, dt in TIMESTEP_POLICY if abs(frequency_hz) <= f), max_timestep)


def capped(dt: float, max_timestep: float) -> float:
    """``dt`` at most ``max_timestep`` (a twin's converged timestep, :attr:`RigParams.max_timestep`) when > 0."""
    return min(dt, max_timestep) if max_timestep > 0 else dt


@dataclass(frozen=True)
class SceneNames:
    stage_joint: str = "stage"
    actuator: str = "stage_servo"
    sole: str = "sole"
    plate: str = "plate"


def build_contact_spec(
    beam: BeamModel,
    twist_deg: float,
    gap_m: float,
    rig: RigParams,
    integrator: str = "implicitfast",
    timestep: float = 1e-4,
) -> mujoco.MjSpec:
    """The contact-rig scene as an ``MjSpec`` (compile it with ``spec.compile()``): plate, stage and clamp,
    the beam, the foot on its tip, the sole–plate pair, the stage actuator and the sensors."""
    names = SceneNames()
    spec = mujoco.MjSpec()
    spec.modelname = "beambench_contact_rig"
    spec.option.timestep = timestep
    spec.option.integrator = INTEGRATORS[integrator]
    spec.option.gravity = [0, 0, -9.81]
    spec.option.solver = SOLVER
    _add_plate(spec, names, -(rig.foot_length + gap_m))
    clamp = _add_stage(spec, names, rig)
    sites = add_beam(clamp, beam, twist_deg)
    _add_foot(spec, names, spec.body(sites.tip_body), rig, [rig.contact_timeconst, rig.contact_dampratio])
    spec.add_pair(
        name="sole_plate",
        geomname1=names.sole,
        geomname2=names.plate,
        condim=3,
        solref=contact_solref(rig, timestep),
        friction=[rig.friction, rig.friction, 0.005, 0.0001, 0.0001],
    )
    spec.add_actuator(
        name=names.actuator,
        target=names.stage_joint,
        trntype=mujoco.mjtTrn.mjTRN_JOINT,
        gaintype=mujoco.mjtGain.mjGAIN_FIXED,
        biastype=mujoco.mjtBias.mjBIAS_AFFINE,
    )
    _add_sensors(spec, names, sites.tip_site)
    return spec


def contact_solref(rig: RigParams, timestep: float) -> list[float]:
    """The sole–plate pair's ``solref`` at ``timestep``: MuJoCo's (time constant, damping ratio), or with
    :attr:`RigParams.contact_matched` the matched direct (−stiffness, −damping) of :func:`matched_solref`."""
    if rig.contact_matched:
        return matched_solref(rig.contact_timeconst, rig.contact_dampratio, timestep)
    return [rig.contact_timeconst, rig.contact_dampratio]


def matched_solref(timeconst: float, dampratio: float, h: float) -> list[float]:
    """A direct ``solref`` (−k, −b) whose discrete contact has the poles of the continuous one at timestep ``h``.

    MuJoCo's soft contact drives the penetration r as r″ = −b·r′ − k·r (at full impedance) with b = 2/tc and
    k = 1/(tc·ζ)², a damped oscillator of ω = 1/(tc·ζ). The step evaluates that reference at the start of the step
    and integrates semi-implicitly (v⁺ = v + h·a, r⁺ = r + h·v⁺): its map has determinant 1 − h·b and trace
    2 − h·b − h²·k, so at h·ω ≈ 0.2 the contact rings slower and loses less per step than the continuous one (the
    first-order timestep error of the contact fraction). Choosing b and k so that determinant and trace equal
    those of the exact map (eigenvalues exp(λ·h)) gives the continuous oscillator's response at every step,
    whatever ``h``; as h → 0 they tend to the plain (2/tc, 1/(tc·ζ)²). At partial impedance d < d_max MuJoCo
    scales b by d/d_max and k by (d/d_max)² in either form, so the match holds at full impedance (d 0.95)."""
    w = SOLIMP_D0 / SOLIMP_DMAX / (timeconst * dampratio)  # the continuous contact's ω at impedance d0
    x = dampratio * w * h
    det = np.exp(-2.0 * x)
    if dampratio < 1.0:
        trace = 2.0 * np.exp(-x) * np.cos(w * h * np.sqrt(1.0 - dampratio**2))
    else:
        trace = 2.0 * np.exp(-x) * np.cosh(w * h * np.sqrt(dampratio**2 - 1.0))
    b = (1.0 - det) / h
    k = (1.0 + det - trace) / h**2
    scale = SOLIMP_DMAX / SOLIMP_D0  # at the shallow penetrations of this contact MuJoCo applies d0/d_max of each
    return [-float(k * scale**2), -float(b * scale)]


def _add_plate(spec: mujoco.MjSpec, names: SceneNames, plate_top: float) -> None:
    """The load-cell plate, its top at ``plate_top``. Only the sole can touch it: one explicit pair, so MuJoCo
    skips the broad phase (contype 0)."""
    world = spec.worldbody
    world.add_geom(
        name=names.plate,
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.06, 0.06, 0.005],
        pos=[0, 0.05, plate_top - 0.005],
        contype=0,
        conaffinity=0,
        rgba=[0.6, 0.6, 0.6, 1],
    )
    world.add_site(name="plate_site", pos=[0, 0.05, plate_top], size=[0.002, 0, 0])


def _add_stage(spec: mujoco.MjSpec, names: SceneNames, rig: RigParams) -> mujoco.MjsBody:
    """The stage on its slide and the clamp welded to it (turned by ``clamp_roll_deg`` about the beam axis)."""
    stage = spec.worldbody.add_body(name="stage")
    stage.add_joint(
        name=names.stage_joint, type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0], armature=rig.stage_armature
    )
    stage.add_geom(
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.02, 0.01, 0.01],
        pos=[0, -0.01, 0],
        mass=rig.stage_mass,
        contype=0,
        conaffinity=0,
        rgba=[0.3, 0.3, 0.3, 1],
    )
    stage.add_site(name="stage", size=[0.002, 0, 0])
    roll = np.radians(rig.clamp_roll_deg)
    clamp = stage.add_body(name="clamp", quat=[np.cos(roll / 2), 0, np.sin(roll / 2), 0])  # welded to the stage
    clamp.add_site(name="clamp", size=[0.001, 0, 0])  # a force sensor here reads the beam's pull on the stage
    return clamp


def _add_foot(spec: mujoco.MjSpec, names: SceneNames, tip: mujoco.MjsBody, rig: RigParams, solref: list) -> None:
    """The rigid foot on the tip body (whose frame is the clamp frame in the natural shape): the frame bar, the
    sole (rigid, or on a compliant slide), the 20 g load at the sole or at the frame's corner, the foot site.
    Parts are placed at their world-aligned offsets rotated back by the clamp roll, so the foot hangs plumb."""
    roll = np.radians(rig.clamp_roll_deg)
    back = np.array([[np.cos(roll), 0, -np.sin(roll)], [0, 1, 0], [np.sin(roll), 0, np.cos(roll)]])

    def at(x: float, y: float, z: float) -> list[float]:
        return [float(v) for v in back @ np.array([x, y, z])]

    r = rig.sole_radius
    corner = rig.sole_at_corner
    offset = (abs(rig.mass_dx) > 0 or abs(rig.mass_dy) > 0) and not corner
    invisible = dict(contype=0, conaffinity=0)
    rigid_frame = rig.frame_gyration > 0 and rig.frame_mass > 0
    tip.add_geom(
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        fromto=at(0, 0, 0) + at(0, 0, -(rig.foot_length - 2 * r)),
        size=[0.002, 0, 0],
        mass=0.0 if rigid_frame else rig.frame_mass,
        rgba=[0.9, 0.5, 0.1, 1],
        **invisible,
    )
    if rigid_frame:  # welded to the tip (no joint): the frame's mass and inertia, given rather than from a shape
        dx, dy = (rig.mass_dx, rig.mass_dy) if corner else (0.0, 0.0)
        frame = tip.add_body(name="load_frame", pos=at(dx / 2, dy / 2, -rig.foot_length / 2))
        frame.explicitinertial = True
        frame.mass = rig.frame_mass
        frame.inertia = [rig.frame_mass * rig.frame_gyration**2] * 3
    sole_at = at(rig.mass_dx if corner else 0, rig.mass_dy if corner else 0, -(rig.foot_length - r))
    if corner:  # the frame's lower cross bar, from below the tip to the corner (visual)
        tip.add_geom(
            type=mujoco.mjtGeom.mjGEOM_CAPSULE,
            fromto=at(0, 0, -(rig.foot_length - 2 * r)) + sole_at,
            size=[0.002, 0, 0],
            mass=0.0,
            rgba=[0.9, 0.5, 0.1, 1],
            **invisible,
        )
    sphere = mujoco.mjtGeom.mjGEOM_SPHERE
    if rig.sole_stiffness > 0:  # a compliant sole: its own body on a damped slide along the foot axis
        if not offset:  # the load stays on the frame, at the sole
            tip.add_geom(
                type=sphere, size=[0.004, 0, 0], pos=sole_at, mass=rig.foot_mass, rgba=[0.5, 0.5, 0.5, 1], **invisible
            )
        sole_body = tip.add_body(name="sole_pad", pos=sole_at)
        stop = dict(limited=1, range=[-0.01, rig.sole_travel], solref_limit=solref) if rig.sole_travel > 0 else {}
        sole_body.add_joint(
            name="sole_slide",
            type=mujoco.mjtJoint.mjJNT_SLIDE,
            axis=at(0, 0, 1),
            stiffness=[rig.sole_stiffness, 0, 0],
            damping=[rig.sole_damping, 0, 0],
            **stop,
        )
        sole_body.add_geom(
            name=names.sole, type=sphere, size=[r, 0, 0], mass=rig.sole_mass, rgba=[0.9, 0.5, 0.1, 1], **invisible
        )
    else:
        mass = 1e-4 if offset else rig.foot_mass
        tip.add_geom(
            name=names.sole, type=sphere, size=[r, 0, 0], pos=sole_at, mass=mass, rgba=[0.9, 0.5, 0.1, 1], **invisible
        )
    if offset:  # the load at the frame's lower corner, mass_dx along the stage travel
        load_at = at(rig.mass_dx, rig.mass_dy, -(rig.foot_length - r))
        tip.add_geom(
            type=sphere, size=[0.004, 0, 0], pos=load_at, mass=rig.foot_mass, rgba=[0.5, 0.5, 0.5, 1], **invisible
        )
    foot_at = at(rig.mass_dx, rig.mass_dy, -rig.foot_length) if corner else at(0, 0, -rig.foot_length)
    tip.add_site(name="foot", pos=foot_at, size=[0.002, 0, 0])


def _add_sensors(spec: mujoco.MjSpec, names: SceneNames, tip_site: str) -> None:
    """Marker positions (stage, beam tip, foot), the stage's velocity and actuator force (the beam's pull on the
    stage follows from them, :meth:`ContactRigSim.stage_pull`) and the sole–plate contact force.

    No force sensor at the clamp: it would make MuJoCo run a post-constraint RNE every step (~10 % of the step)
    for a channel the stage's own balance gives exactly."""
    site, joint = mujoco.mjtObj.mjOBJ_SITE, mujoco.mjtObj.mjOBJ_JOINT
    for marker, name in zip(CONTACT_MARKERS, ("stage", tip_site, "foot")):
        spec.add_sensor(name=marker, type=mujoco.mjtSensor.mjSENS_FRAMEPOS, objtype=site, objname=name)
    spec.add_sensor(name="stage_vel", type=mujoco.mjtSensor.mjSENS_JOINTVEL, objtype=joint, objname=names.stage_joint)
    spec.add_sensor(
        name="stage_act", type=mujoco.mjtSensor.mjSENS_JOINTACTFRC, objtype=joint, objname=names.stage_joint
    )
    # contact sensor: data = found + force (bits 0, 1), reduce = netforce (3), one slot; global frame
    spec.add_sensor(
        name="plate_force",
        type=mujoco.mjtSensor.mjSENS_CONTACT,
        objtype=mujoco.mjtObj.mjOBJ_GEOM,
        objname=names.sole,
        reftype=mujoco.mjtObj.mjOBJ_GEOM,
        refname=names.plate,
        intprm=[3, 3, 1],
    )


class ContactRigSim(DrivenScene):
    """The contact rig advanced in chunks; channels: ``markers`` [n, 3, 3] (stage, tip, foot), ``force_nt``
    [n, 2] (plate normal, tangential-x, N), and the motor's ``theta``/``omega``/``setpoint``/``torque``."""

    rig: RigParams
    thermal: ThermalState | None = None  # sim.thermal_drift: the beam softens as it warms (sim.models.thermal)

    markers = CONTACT_MARKERS

    def __init__(
        self,
        beam: BeamModel,
        twist_deg: float = 90.0,
        gap_m: float | None = None,
        amplitude_m: float = 0.002,
        rig: RigParams | None = None,
        integrator: str = "implicitfast",
        timestep: float | None = None,
        timestep_for: Callable[[float], float] | None = None,
        selection: dict | None = None,
    ) -> None:
        self.rig = rig or RigParams.with_overrides(beam.params.rig)
        gap = self.rig.plate_gap if gap_m is None else gap_m
        self.beam, self.twist_deg, self.gap_m, self.amplitude = beam, twist_deg, gap, amplitude_m
        self.integrator = integrator
        self.fixed_timestep = timestep
        # the timestep each frequency needs: the rig's policy, or a plan from beambench.sim.selection (model: auto)
        # capped at the twin's converged timestep (RigParams.max_timestep), a plan's too
        base, cap = timestep_for or default_timestep, self.rig.max_timestep
        self.timestep_for = lambda hz: capped(base(hz), cap)
        self.selection = selection
        h0 = timestep or self.timestep_for(1.0)
        self.spec = build_contact_spec(beam, twist_deg, gap, self.rig, integrator, h0)
        model = self.spec.compile()
        skip_unused_stages(model)
        super().__init__(Physics(model))
        if self.rig.contact_matched:  # the pair's solref follows the timestep
            pair = model.pair("sole_plate").id
            self.physics.on_timestep = lambda h: model.pair_solref.__setitem__(pair, contact_solref(self.rig, h))
        self.ramp = VelocityRamp(self.rig.vel_ramp_rate)
        stage_dof = self._stage_dof = int(model.jnt_dofadr[model.joint("stage").id])
        # the slider's own inertia: armature + the stage body (the beam acts on it as an external load)
        self._m_stage = float(model.dof_armature[stage_dof] + model.body("stage").mass[0])
        self.servo = KinematicServo(model, "stage_servo", self._m_stage, self.rig.servo_hz, integrator, h0)
        # beam.loss_factor > 0: the beam's dampers follow the drive frequency (sim.models.hysteretic), not beta
        loss = float(beam.params.loss_factor)
        self.damping = HystereticDamping.of(model, loss) if loss > 0 else None
        if self.damping is not None:
            self.damping.at(model, 0.0)
        self.physics.reset_to_equilibrium(self.rig.preroll_s, np.zeros(1))

    # --- commands -------------------------------------------------------------------------------------
    def set_frequency(self, hz: float) -> None:
        """New crank-speed setpoint (turn/s = Hz); also picks the timestep the frequency needs."""
        self.ramp.setpoint = float(hz)
        if self.damping is not None:
            self.damping.at(self.physics.model, hz)
        if self.fixed_timestep is None:
            self.physics.set_timestep(self.timestep_for(max(abs(hz), abs(self.ramp.omega))))

    def enable_thermal(self, params: ThermalParams) -> None:
        """Thermal drift from now on, starting cold (ΔT = 0)."""
        self.thermal = thermal_state(self.physics.model, params)

    # --- stepping -------------------------------------------------------------------------------------
    def advance_to(self, t_target: float) -> Trajectory:
        """The rows up to ``t_target``; with thermal drift, at the stiffness of the beam's temperature before the
        chunk, which then warms by the chunk's drive power."""
        th = self.thermal
        if th is None:
            return super().advance_to(t_target)
        th.apply(self.physics.model)
        traj = super().advance_to(t_target)
        if len(traj):
            ch = traj.channels
            power = stage_power(traj.t, ch["markers"][:, 0, 0], ch["pull_x"])
            th.heat(power, len(traj) * self.physics.timestep)
        return traj

    def step_cost(self, hz: float) -> float:
        """The physics' relative cost per simulated second at ``hz``: steps per second at the timestep it runs
        (``CostsByFrequency``: the sim rig balances its segments with it)."""
        h = self.fixed_timestep or self.timestep_for(abs(hz))
        return 1e-4 / h

    def same_regime(self, a: Trajectory, b: Trajectory, hz: float) -> bool:
        """Two runs of one step in the same regime (``ChecksCuts``: the sim rig checks each segment cut with it)."""
        from beambench.sim.scenes.step_regime import steps_agree

        return steps_agree(a, b, hz)

    def _plan(self, n: int, h: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        omega, theta = self.ramp.plan(n, h)
        ref = self.amplitude * np.sin(theta)  # rows 0..n
        ctrl, acc = self.servo.controls(ref, h)
        motor = {"theta": theta[:-1], "omega": omega[:-1], "setpoint": np.full(n, self.ramp.setpoint), "stage_acc": acc}
        return ctrl[:, None], motor

    def _channels(self, sens: np.ndarray) -> dict[str, np.ndarray]:
        n = len(sens)
        markers = np.stack([self.sensor(sens, m) for m in CONTACT_MARKERS], axis=1)
        plate = self.sensor(sens, "plate_force")  # found, fx, fy, fz: force of the foot on the plate
        force_nt = np.column_stack([-plate[:, 3], plate[:, 1]])
        pull_x = self.stage_pull(self.sensor(sens, "stage_vel")[:, 0], self.sensor(sens, "stage_act")[:, 0])
        return {"markers": markers.reshape(n, len(CONTACT_MARKERS), 3), "force_nt": force_nt, "pull_x": pull_x}

    def stage_pull(self, v: np.ndarray, f_act: np.ndarray) -> np.ndarray:
        """The beam's force on the stage along the travel x (N) during each step of the chunk just stepped, from
        the stage's balance: M·a = f_act + F_beam, with a = (v[k+1] − v[k])/h the acceleration the step realised
        (the last one from the state the chunk ends in) and, for the implicit integrators, the actuator's force
        as the step applies it (f_act − h·kv·a)."""
        h = self.physics.timestep
        v_next = np.append(v[1:], self.physics.data.qvel[self._stage_dof])
        a = (v_next - v) / h
        m_eff = self._m_stage + (h * self.servo.kv if self.servo.implicit else 0.0)
        return np.asarray(m_eff * a - f_act)

    def motor_torque(self, traj_channels: dict[str, np.ndarray]) -> np.ndarray:
        """Crank torque (N·m) from the stage force by virtual work: τ = F·dx/dθ = F·A·cos θ, plus friction."""
        ch = traj_channels
        force = self.rig.stage_mass * ch["stage_acc"] - ch["pull_x"]
        tau = force * self.amplitude * np.cos(ch["theta"])
        return tau + self.rig.friction_torque * np.tanh(ch["omega"] / 0.05)

    def identity(self) -> dict[str, Any]:
        m = self.physics.model
        return {
            "scene": "contact_rig",
            **self.beam.describe(),
            "twist_deg": self.twist_deg,
            "plate_gap_m": self.gap_m,
            "amplitude_m": self.amplitude,
            "rig_params": asdict(self.rig),
            "integrator": self.integrator,
            **({"loss_factor": self.damping.loss_factor} if self.damping is not None else {}),
            "timestep": self.fixed_timestep if self.fixed_timestep else "auto",
            "timestep_policy": "fixed"
            if self.fixed_timestep
            else "auto: " + ", ".join(f"{dt:g} s up to {f:g} Hz" for f, dt in TIMESTEP_POLICY) + _cap_note(self.rig),
            "nq": int(m.nq),
            "nv": int(m.nv),
            "mujoco_version": mujoco.__version__,
            **({"selection": self.selection} if self.selection else {}),
            **({"thermal_drift": self.thermal.describe()} if self.thermal is not None else {}),
        }


def _cap_note(rig: RigParams) -> str:
    return f", at most {rig.max_timestep:g} s (this twin's converged timestep)" if rig.max_timestep > 0 else ""


# --- scene registration (beambench.sim.scenes.registry) --------------------------------------------------------
@register(CONTACT)
def build(cfg: SceneConfig) -> ContactRigSim:
    """The contact rig of a protocol: its plate gap (None: the parameter set's), stage amplitude and measured plan."""
    sim = cfg.sim
    plan = sim.plan
    scene = ContactRigSim(
        cfg.beam,
        twist_deg=sim.settings.twist_deg,
        gap_m=sim.plate_gap_m,
        amplitude_m=sim.settings.amplitude_m,
        integrator=sim.integrator,
        timestep=sim.timestep,
        timestep_for=plan.timestep if plan else None,
        selection=plan.describe() if plan else None,
    )
    td = sim.thermal
    if td is not None:
        c = td.heat_capacity_j_per_k or cfg.beam.params.mass * CP_TPU
        scene.enable_thermal(ThermalParams(td.alpha_per_k, td.tau_s, c, td.heated_fraction))
    return scene
