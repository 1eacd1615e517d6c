"""The scenes' constants as plain dataclasses, without MuJoCo: the contact rig's :class:`RigParams` and the
walker's :class:`WalkerParams`. A parameter set's ``rig:`` and ``walker:`` blocks override them, and the input
checks (``--dry-run`` included) read their fields here without building a scene."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any


@dataclass(frozen=True)
class RigParams:
    """Contact-rig constants (SI). A parameter set may override any of them in its ``rig:`` block."""

    foot_length: float = 0.0665  # m, beam tip to sole bottom
    # m, h' of the paper: the plate's top below the sole in the beam's UNLOADED (natural, gravity-free) shape;
    # the sag under gravity is the rig's own business (a sag larger than the gap is a preload)
    plate_gap: float = 0.0055
    foot_mass: float = 0.020  # kg, the load on the foot frame (paper: 20 g), at the sole unless mass_dx
    # m, offset of that mass from the sole along x (stage travel); the paper puts the 20 g "at the lower left
    # corner of the load frame" without giving the offset — an offset mass twists the tip
    mass_dx: float = 0.0
    mass_dy: float = 0.0  # m, the same along y (the beam's axis, away from the stage)
    # the frame meets the plate at that lower corner (the paper's load frame), not below the tip: the sole sits
    # with the load, and h' is the corner's clearance in the unloaded shape
    sole_at_corner: bool = False
    # kg, the load frame's own mass, spread along the foot (tip to sole); the paper gives only the 20 g load
    frame_mass: float = 0.0
    # m, the load frame as one rigid body: its own mass at the frame's centroid (halfway down the bar, halfway to
    # the corner) with an isotropic inertia frame_mass * frame_gyration**2 about it; 0 = the mass spread along the
    # bar (a thin rod: gyration foot_length/sqrt(12) about the horizontal axes, none about the bar)
    frame_gyration: float = 0.0
    # deg, the beam's section turned about its own axis at the clamp: 0 = as built (width vertical at the
    # clamp, weak bending along the stage travel, see beambench.sim.models.beam), 90 = flat face horizontal
    # at the root; the foot still hangs plumb below the tip
    clamp_roll_deg: float = 0.0
    sole_radius: float = 0.003  # m
    # N/m and N·s/m, the sole's own compliance along the foot axis (a lossy pad between the load frame and
    # the plate: TPU sole, frame, load-cell plate mount in series); 0 = a rigid sole on the frame
    sole_stiffness: float = 0.0
    sole_damping: float = 0.0
    sole_mass: float = 0.001  # kg, the part of the sole that moves with the plate (only with sole_stiffness)
    # m, how far the compliant sole compresses before the frame bottoms out on it (a hard stop, the contact's
    # solref); 0 = no stop
    sole_travel: float = 0.0
    plate_from_stage: float = 0.072  # m, informational: foot_length + the paper's 5.5 mm gap
    friction: float = 0.5
    contact_timeconst: float = 0.001  # s (≤ 2 ms needed; MuJoCo's default 20 ms hides the contact effects)
    contact_dampratio: float = 1.0
    # the contact's spring–damper discretised so that its poles at the run's timestep are those of the continuous
    # contact (beambench.sim.scenes.contact_rig.matched_solref): the same physics, its time constant resolved at a
    # larger timestep
    contact_matched: bool = False
    stage_armature: float = 1000.0  # kg, makes the stage a near-kinematic drive
    stage_mass: float = 0.15  # kg, the physical carriage (for the motor current estimate)
    servo_hz: float = 30.0  # bandwidth of the stage's feedback (feed-forward does the tracking)
    vel_ramp_rate: float = 50.0  # turn/s², ODrive controller.config.vel_ramp_rate
    torque_constant: float = 8.27 / 150  # N·m/A (D6374 150 KV)
    friction_torque: float = 0.02  # N·m, crank + bearings (Coulomb)
    bus_voltage: float = 24.0  # V
    preroll_s: float = 0.5  # settle to the static equilibrium before t = 0
    # s, the largest timestep this twin's answers are converged at (measured with
    # benchmarks/bench_contact_convergence.py); caps the frequency policy below; 0 = the policy alone
    max_timestep: float = 0.0

    @classmethod
    def with_overrides(cls, overrides: dict[str, Any]) -> RigParams:
        known = {f.name for f in fields(cls)}
        bad = set(overrides) - known
        if bad:
            raise ValueError(f"rig.{sorted(bad)[0]}: unknown rig parameter")
        flags = {f.name for f in fields(cls) if f.type in (bool, "bool")}
        values: dict[str, Any] = {k: bool(v) if k in flags else float(v) for k, v in overrides.items()}
        return cls(**values)


# Where each number comes from: P = the paper (Sec. IV-B, Fig. 5a); D = Maxon EC 45 flat Ø42.9 mm 30 W datasheet
# (article 200142, Hall sensors, 12 V winding; May 2012 edition; line numbers are the datasheet's); C = calibrated
# to the paper's two speeds (a 2-D scan, settle 3 s; the calibrator ``beambench calibrate sim`` redoes it);
# G = guessed (the paper is silent; the module docstring and benchmarks/bench_walker.py give what each does);
# N = numerics (converged, benchmarks/bench_walker.py).
@dataclass(frozen=True)
class WalkerParams:
    """Walker constants (SI). Source of each number in the comment: P paper, D datasheet, C calibrated,
    G guessed, N numerics (see the legend above the class). Flags are floats (0/1) so that ``with_overrides``
    can read them. :meth:`named` gives the named sets (``calibrated`` = the defaults, ``paper_guesses``)."""

    plate_mass: float = 0.045  # G: carbon-fibre plate (paper: material only)
    motor_mass: float = 0.110  # G: EC 45 flat class; the datasheet's weight line was not retrieved (not verified)
    eccentric_mass: float = 0.040  # P: "a 40 g offset load"
    eccentric_radius: float = 0.010  # G: offset radius (sensitivity: 5/15 mm move 23 Hz by ~±10 mm/s)
    rotor_inertia: float = 9.25e-6  # D line 16: 92.5 g·cm² (all windings)
    cart_mass: float = 0.100  # P: "a cart with a 100 g load"
    length: float = 0.295  # P: 295 mm platform, plate front to cart tail
    leg_offset: float = 0.03  # G: clamp distance from the centre line (≈ no effect on the speed)
    foot_length: float = 0.0665  # P (Sec. IV-A): 66.5 mm foot
    # C: point mass at each sole (paper_guesses: 20 g, the Sec. IV-A foot load). A steady 2-D scan: 3.0 g
    # at μ 0.5 → −35.5 / +154.7 mm/s at 23 / 65 Hz; `beambench calibrate sim` on the paper's targets (540 s budget)
    # lands in the same basin (3.3 g, μ 0.507 → −36.3 / +138.8)
    foot_mass: float = 0.003
    foot_bar_mass: float = 0.0  # G: mass of each rigid foot bar (spread along it)
    frame_mass: float = 0.0  # G: the boom from the plate to the cart
    sole_radius: float = 0.003  # G: 3 mm sphere sole
    wheel_radius: float = 0.008  # G: cart wheels (frictionless)
    friction: float = 0.5  # C: sole-floor Coulomb friction, jointly with foot_mass (usable band 0.45-0.52)
    contact_timeconst: float = 0.0003  # N: solref time constant, converged with the timestep (module docstring)
    contact_dampratio: float = 1.0  # N: critically damped contact
    servo_hz: float = 300.0  # N: rotor angle servo bandwidth (the ODrive holds the commanded speed)
    vel_ramp_rate: float = 200.0  # turn/s²: the drive's ODrive ramp, calibration/rig.yaml walker.vel_ramp_rate_turn_s2
    spin: float = -1.0  # G: rotor turns about -y (with the legs below: backward at 23 Hz, forward above ~27 Hz)
    left_chirality: float = -1.0  # P: mirrored legs, left twisted -φ, right +φ
    right_chirality: float = 1.0  # P
    motor_radius: float = 0.02145  # P footnote / D: Ø42.9 mm
    rotor_height: float = 0.023  # G: motor axis above the leg clamps: plate half-thickness + motor radius
    motor_x: float = 0.0  # G: the motor's axis along the body, + ahead of the leg clamps (toward the cart: −)
    motor_flat: float = (
        0.0  # G: motor axis along y (0: offset mass turns in x–z), vertical (1: x–y) or along x (2: y–z)
    )
    leg_mount_deg: float = 0.0  # G: leg rake about the lateral axis; + = soles toward the cart
    leg_droop_deg: float = 0.0  # G: the legs' angle below the horizontal at the clamp (0 sideways, 90 hanging down)
    leg_roll_deg: float = 0.0  # G: each clamp turned about its leg's axis (0: width vertical at the clamp, 90: flat)
    lateral_free: float = 0.0  # P: 1 = let the body slide sideways (the paper's slider holds it; see above)
    torque_constant: float = 0.0255  # D line 12: 25.5 mN·m/A (12 V winding 200142; the walker's winding is unknown)
    bus_voltage: float = 24.0  # G: ODrive bus
    preroll_s: float = 0.5  # N: motor off, settle under gravity (a quenched half, then a free half)
    timestep: float = 1.2e-4  # N: converged with the contact time constant above (halving both: ≤ 1 %)

    @classmethod
    def named(cls, name: str) -> WalkerParams:
        """A named parameter set: ``calibrated`` (the defaults: foot 3 g, friction 0.5, datasheet rotor inertia)
        or ``paper_guesses`` (before calibration: foot 20 g, rotor 135 g·cm² "EC 45 flat class")."""
        if name not in PARAMETER_SETS:
            raise ValueError(f"walker parameter set {name!r}: one of {', '.join(PARAMETER_SETS)}")
        return cls(**PARAMETER_SETS[name])

    @classmethod
    def with_overrides(cls, overrides: dict[str, Any]) -> WalkerParams:
        known = {f.name for f in fields(cls)}
        return cls(**{k: float(v) for k, v in overrides.items() if k in known})


PARAMETER_SETS: dict[str, dict[str, float]] = {
    "calibrated": {},
    "paper_guesses": {"foot_mass": 0.020, "rotor_inertia": 1.35e-5},
}
