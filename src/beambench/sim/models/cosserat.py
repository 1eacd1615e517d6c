"""PyElastica Cosserat rod of the twisted beam: an independent cross-check of the segmented rod (:mod:`.rod`).

Same beam as :class:`beambench.sim.models.rod.RodParams` (E, G = E/2(1 + ν), the rectangular w × t section, length,
the *same total mass* — by default the weighed 5.17 g spread along the length, as our rods and PRB3 do) but a
different discretisation and integrator: a shearable, extensible Cosserat rod of ``n_elements`` elements stepped
explicitly (PositionVerlet), against MuJoCo's rigid segments joined by hinge springs.

Mapping onto PyElastica (a round section by default, so the section is set by hand after construction):

- ``base_radius = √(w·t/π)`` gives the element volume and nodal masses of the rectangle; the bend matrix is
  replaced by diag(EI_weak, EI_strong, GJ) (GJ from the same Saint-Venant formula as the rod), the shear matrix by
  diag(κGA, κGA, EA) with Cowper's κ = 10(1 + ν)/(12 + 11ν) for a rectangle (``shear_factor`` scales κGA; a
  large value makes the rod Euler–Bernoulli-like), and the mass second moment of inertia by
  ρ·Δs·diag(w t³/12, t w³/12, (w t³ + t w³)/12).
- Directors: d1 = width axis, d2 = thickness axis, d3 = tangent, so bending about d1 is the weak bending. The
  clamp frame of :mod:`beambench.sim.models.beam` is kept (rod along +y, width along z and thickness along x at the root);
  element i is turned about +y by θ = φ·s_i/L (φ > 0 right-handed, as the segmented rod) and the rest curvature
  and strain are set to those of this twisted shape, so the natural shape is straight and pre-twisted.
- Drive: the rod is simulated in the stage frame. The clamp (node 0 and element 0) is fixed, and every node gets
  the inertial force −m·ẍ_stage = m·A·ω²·sin(ωt) along x plus gravity; the world tip is the tip node plus
  x_stage(t). A pure translation of the frame adds no other fictitious forces, so this is exact.
- Damping: PyElastica 1.0 has no internal (strain-rate) dissipation, so our stiffness-proportional b = β·k cannot be
  reproduced. The closest it allows is :class:`elastica.AnalyticalLinearDamper` with a ``uniform_damping_constant``
  α (v, ω ← exp(−α·dt)·(v, ω)): mass-proportional Rayleigh damping. Applied in the stage frame it damps the
  motion *relative to the clamp* only, as b = β·k does. Choosing α = β·ω₁² (ω₁ = the first weak-bending mode)
  gives the first mode exactly the same damping force as β·k at every drive frequency (ζ₁ = β·ω₁/2 ≈ 0.045);
  higher modes get less damping than with β·k (ζ ∝ 1/ω instead of ∝ ω), which matters only near their
  resonances (above the 45 Hz of the sweep).
- Start: like :func:`beambench.sim.scenes.free_beam.run_batch` — the beam at rest under gravity relative to a stage at
  x = 0 moving at v = A·ω. The gravity sag is found once by a heavily damped pre-run (α = 2ω₁ for ``presettle_s``)
  and every frequency starts from that state.

PyElastica is an optional dependency: it is imported inside the functions, so this module imports without it.
The first call in a process spends ~20 s compiling PyElastica's numba kernels.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from beambench.common.types import Floats
from beambench.sim.models.params import BeamParams, load_params
from beambench.sim.models.rod import RodParams

GRAVITY = 9.81


@dataclass(frozen=True)
class CosseratParams:
    """A Cosserat rod of the beam: section, material and mass from a :class:`RodParams` (SI units)."""

    rod: RodParams = field(default_factory=RodParams)
    n_elements: int = 20
    timestep: float = 1e-5  # s, PositionVerlet (explicit: n = 20 is stable at 1e-5, n = 40 needs ~5e-6)
    shear_factor: float = 1.0  # scales κGA (Timoshenko shear); ≫ 1 nears Euler–Bernoulli (10: needs dt 2.5e-6)
    damping_hz: float | None = None  # frequency at which α = β·ω² matches β·k; default: first weak mode

    @classmethod
    def from_beam(
        cls,
        beam: BeamParams | str = "paper",
        n_elements: int = 20,
        timestep: float = 1e-5,
        mass: str = "measured",
        **kw: Any,
    ) -> CosseratParams:
        """From a rod parameter set (``sim_backend/rod_<name>.yaml``); ``mass`` as in :meth:`RodParams.from_beam`."""
        bp = load_params(beam, model="rod") if isinstance(beam, str) else beam
        return cls(rod=RodParams.from_beam(bp, mass=mass), n_elements=n_elements, timestep=timestep, **kw)

    @property
    def shear_coefficient(self) -> float:
        """Cowper's shear coefficient of a rectangle, 10(1 + ν)/(12 + 11ν)."""
        nu = self.rod.poisson
        return 10 * (1 + nu) / (12 + 11 * nu)

    @property
    def alpha(self) -> float:
        """Mass-proportional damping constant α = β·ω_match² (1/s) matching the rod's β·k at ``damping_hz``."""
        f = self.damping_hz if self.damping_hz is not None else self.rod.first_frequency("weak")
        return self.rod.beta * (2 * math.pi * f) ** 2


@dataclass
class CosseratSweep:
    """Tip paths over frequencies, shaped like :class:`beambench.sim.scenes.free_beam.SweepResult`: ``tip`` [nf, n, 3]
    (m, world frame of the free-beam scene), ``stage`` [nf, n] (m) at ``t`` [n] (s); ``ok`` False where a run
    went non-finite; ``wall_s`` the seconds spent stepping (excluding the shared pre-settle and compilation)."""

    t: np.ndarray
    tip: np.ndarray
    stage: np.ndarray
    ok: np.ndarray
    frequencies: np.ndarray
    twist_deg: float
    timestep: float
    wall_s: float
    info: dict = field(default_factory=dict)


def _section_matrices(
    p: CosseratParams, rest_lengths: np.ndarray, twist_deg: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-element shear [3, 3, n] and mass second moment [3, 3, n]; per-Voronoi bend matrix [3, 3, n − 1]
    (torsion: the pre-twisted strip's GJ with the trapeze term, as the segmented rod has it)."""
    r = p.rod
    n = len(rest_lengths)
    a = r.area
    ga = p.shear_factor * p.shear_coefficient * r.shear_modulus * a
    shear = np.zeros((3, 3, n))
    shear[0, 0], shear[1, 1], shear[2, 2] = ga, ga, r.youngs_modulus * a
    i1 = r.width * r.thickness**3 / 12  # about d1 (width axis): weak
    i2 = r.thickness * r.width**3 / 12  # about d2 (thickness axis): strong
    inertia = np.zeros((3, 3, n))
    inertia[0, 0], inertia[1, 1], inertia[2, 2] = (r.density * rest_lengths * v for v in (i1, i2, i1 + i2))
    bend = np.zeros((3, 3, n - 1))
    bend[0, 0], bend[1, 1], bend[2, 2] = r.ei_weak, r.ei_strong, r.torsion_gj(twist_deg)
    return shear, inertia, bend


def element_length(length: float, n: int) -> float:
    """Element length Δs = L/(n − ½): the rod starts Δs/2 behind the clamp (see :class:`CosseratBeam`)."""
    return length / (n - 0.5)


def twisted_directors(n: int, twist_deg: float) -> np.ndarray:
    """Directors [3, 3, n] (rows d1 = width, d2 = thickness, d3 = tangent +y) of elements turned about +y by
    θ_i = φ·s_i/L, with element i centred at s_i = i·Δs, Δs = L/(n − ½) (element 0, the clamped one, at s = 0)."""
    theta = math.radians(twist_deg) * np.arange(n) / (n - 0.5)
    c, s = np.cos(theta), np.sin(theta)
    q = np.zeros((3, 3, n))
    q[0, 0], q[0, 2] = s, c  # d1 = R_y(θ)·z
    q[1, 0], q[1, 2] = c, -s  # d2 = R_y(θ)·x
    q[2, 1] = 1.0  # d3 = y
    return q


class CosseratBeam:
    """One PyElastica simulator of the clamped, pre-twisted beam in the stage frame (see the module docstring).

    Clamp: PyElastica's :class:`elastica.OneEndFixedBC` holds node 0 and the director of element 0, so the first
    bending compliance sits at node 1, the Voronoi point standing for [Δs/2, 3Δs/2]. To put the compliance
    where the material is, the rod starts Δs/2 *behind* the clamp and is L + Δs/2 long (Δs = L/(n − ½)): the
    compliant material then spans [0, L − Δs/2] (the missing end piece carries almost no moment), the tip node is
    at s = L, and the moving nodes 1…n carry exactly the beam's mass (node 0's half element is held). Without
    this the static tip deflection is ~2Δs/L too small (9 % at n = 20).

    ``gravity`` is a world vector (default −z, as the free-beam scene); ``set_drive(f, A)`` sets the stage
    sine; :meth:`step` advances by ``n`` steps of ``params.timestep``.
    """

    def __init__(
        self,
        params: CosseratParams,
        twist_deg: float = 90.0,
        gravity: Floats = (0.0, 0.0, -GRAVITY),
        damping: bool = True,
    ) -> None:
        import elastica as ea

        self.params = p = params
        r = p.rod
        n = p.n_elements
        directors = twisted_directors(n, twist_deg)

        class _Sim(ea.BaseSystemCollection, ea.Constraints, ea.Forcing, ea.Damping):
            pass

        beam = self

        class _StageFrameLoads(ea.NoForces):
            """Gravity and the stage-frame inertial force m·A·ω²·sin(ωt) along x on every node."""

            def apply_forces(self, system: Any, time: float = 0.0) -> None:
                m = system.mass
                g = beam.gravity
                system.external_forces[0] += m * g[0]
                system.external_forces[1] += m * g[1]
                system.external_forces[2] += m * g[2]
                if beam.frequency > 0 and time >= 0:
                    w = 2 * math.pi * beam.frequency
                    system.external_forces[0] += m * (beam.amplitude * w * w * math.sin(w * time))

        sim = _Sim()
        ds = element_length(r.length, n)
        rod = ea.CosseratRod.straight_rod(
            n,
            np.array([0.0, -ds / 2, 0.0]),
            np.array([0.0, 1.0, 0.0]),
            np.array([0.0, 0.0, 1.0]),
            n * ds,
            math.sqrt(r.area / math.pi),
            r.density,
            youngs_modulus=r.youngs_modulus,
            shear_modulus=r.shear_modulus,
            directors=directors,
        )
        shear, inertia, bend = _section_matrices(p, rod.rest_lengths, twist_deg)
        rod.shear_matrix[:] = shear
        rod.bend_matrix[:] = bend
        rod.mass_second_moment_of_inertia[:] = inertia
        for i in range(n):
            rod.inv_mass_second_moment_of_inertia[..., i] = np.linalg.inv(inertia[..., i])
        rod.rest_kappa[:] = rod.kappa  # the twisted shape is the natural shape
        rod.rest_sigma[:] = rod.sigma
        sim.append(rod)
        sim.constrain(rod).using(ea.OneEndFixedBC, constrained_position_idx=(0,), constrained_director_idx=(0,))
        sim.add_forcing_to(rod).using(_StageFrameLoads)
        if damping:
            sim.dampen(rod).using(ea.AnalyticalLinearDamper, uniform_damping_constant=p.alpha, time_step=p.timestep)
        sim.finalize()
        self.gravity = np.asarray(gravity, float)
        self.frequency = 0.0
        self.amplitude = 0.0
        self.sim, self.rod = sim, rod
        self.stepper = ea.PositionVerlet()
        self.time = np.float64(0.0)

    def set_drive(self, frequency: float, amplitude: float) -> None:
        self.frequency, self.amplitude = float(frequency), float(amplitude)

    def step(self, n: int, extra_damping: float = 0.0) -> None:
        """``n`` steps; ``extra_damping`` (1/s) further scales v and ω by exp(−c·dt) per step (pre-settling)."""
        dt = self.params.timestep
        decay = math.exp(-extra_damping * dt)
        for _ in range(n):
            self.time = self.stepper.step(self.sim, self.time, dt)
            if extra_damping:
                self.rod.velocity_collection *= decay
                self.rod.omega_collection *= decay

    def settle(self, seconds: float = 0.1) -> None:
        """Come to rest under gravity (drive off) with α = 2ω₁ extra damping; then zero rates and time."""
        self.set_drive(0.0, 0.0)
        w1 = 2 * math.pi * self.params.rod.first_frequency("weak")
        self.step(round(seconds / self.params.timestep), extra_damping=2 * w1)
        self.rod.velocity_collection[:] = 0.0
        self.rod.omega_collection[:] = 0.0
        self.time = np.float64(0.0)

    def snapshot(self) -> tuple[np.ndarray, ...]:
        r = self.rod
        return tuple(
            a.copy() for a in (r.position_collection, r.director_collection, r.velocity_collection, r.omega_collection)
        )

    def restore(self, state: tuple[np.ndarray, ...]) -> None:
        r = self.rod
        for dst, src in zip(
            (r.position_collection, r.director_collection, r.velocity_collection, r.omega_collection), state
        ):
            dst[:] = src
        self.time = np.float64(0.0)

    @property
    def tip(self) -> np.ndarray:
        """Tip node position in the stage frame (m)."""
        return self.rod.position_collection[:, -1].copy()


def frequency_sweep(
    frequencies: Floats,
    twist_deg: float = 90.0,
    params: CosseratParams | None = None,
    amplitude: float = 0.002,
    settle_s: float = 1.0,
    record_s: float = 0.5,
    sample_dt: float = 1e-4,
    gravity: bool = True,
    presettle_s: float = 0.1,
) -> CosseratSweep:
    """Steady-state tip paths at each frequency, sampled as :func:`beambench.sim.scenes.free_beam.frequency_sweep`
    with ``timestep = sample_dt``: the same window (every step time k·sample_dt in [settle_s, settle_s +
    record_s)) and the world frame of the free-beam scene (stage travel x, beam along y, z up)."""
    from beambench.sim.engine.batch import window

    p = params or CosseratParams.from_beam()
    every = round(sample_dt / p.timestep)
    if every < 1 or abs(every * p.timestep - sample_dt) > 1e-12:
        raise ValueError(f"sample_dt = {sample_dt} must be a whole multiple of the timestep {p.timestep}")
    n_total, keep = window(settle_s, record_s, sample_dt)
    beam = CosseratBeam(p, twist_deg, (0.0, 0.0, -GRAVITY if gravity else 0.0))
    t0 = time.perf_counter()
    beam.settle(presettle_s)
    settle_wall = time.perf_counter() - t0
    rest = beam.snapshot()
    freqs = np.asarray(frequencies, float)
    t = keep * sample_dt
    tip = np.full((len(freqs), len(keep), 3), np.nan)
    ok = np.ones(len(freqs), bool)
    walls = []
    for i, f in enumerate(freqs):
        beam.restore(rest)
        beam.set_drive(f, amplitude)
        t0 = time.perf_counter()
        j = 0
        for k in range(n_total):
            if j < len(keep) and keep[j] == k:
                tip[i, j] = beam.tip
                j += 1
            beam.step(every)
            if k % 1000 == 0 and not np.isfinite(beam.rod.position_collection).all():
                ok[i] = False
                break
        walls.append(time.perf_counter() - t0)
        if not np.isfinite(tip[i]).all():
            ok[i] = False
    stage = amplitude * np.sin(2 * np.pi * freqs[:, None] * t[None, :])
    tip[:, :, 0] += stage
    return CosseratSweep(
        t,
        tip,
        stage,
        ok,
        freqs,
        float(twist_deg),
        p.timestep,
        float(sum(walls)),
        {
            "model": f"cosserat{p.n_elements}",
            "alpha": p.alpha,
            "presettle_wall_s": settle_wall,
            "wall_per_run_s": walls,
            "simulated_per_run_s": float(n_total * sample_dt),
            "simulated_s": float(len(freqs) * n_total * sample_dt),
            "amplitude": amplitude,
            "gravity": gravity,
        },
    )


def static_tip(
    params: CosseratParams,
    twist_deg: float = 0.0,
    gravity: Floats = (0.0, 0.0, -GRAVITY),
    seconds: float = 0.15,
) -> np.ndarray:
    """Tip displacement (m, stage frame) at rest under ``gravity`` (heavily damped run; drive off)."""
    beam = CosseratBeam(params, twist_deg, gravity, damping=False)
    tip0 = beam.tip
    beam.settle(seconds)
    return beam.tip - tip0


def first_frequency(
    params: CosseratParams, axis: str = "weak", twist_deg: float = 0.0, seconds: float = 0.25, load: float = GRAVITY
) -> float:
    """First natural frequency (Hz) about ``axis`` ("weak": motion along x, "strong": along z) from free
    vibration: the rod comes to rest under a uniform load ``load``·m along the axis, the load is released and the
    undamped tip motion is timed over ``seconds`` (mean period between the first and last upward zero
    crossings, interpolated)."""
    g = (-load, 0.0, 0.0) if axis == "weak" else (0.0, 0.0, -load)
    beam = CosseratBeam(params, twist_deg, g, damping=False)
    k = 0 if axis == "weak" else 2
    rest = beam.tip[k]
    beam.settle(0.1)
    beam.gravity = np.zeros(3)
    dt = params.timestep
    every = max(1, round(2e-5 / dt))
    n = round(seconds / (every * dt))
    x = np.empty(n)
    for i in range(n):
        x[i] = beam.tip[k] - rest
        beam.step(every)
    up = np.nonzero((x[:-1] < 0) & (x[1:] >= 0))[0]
    if len(up) < 2:
        raise ValueError(f"first_frequency: fewer than two oscillations in {seconds} s")
    tc = (up + x[up] / (x[up] - x[up + 1])) * every * dt
    return (len(tc) - 1) / (tc[-1] - tc[0])
