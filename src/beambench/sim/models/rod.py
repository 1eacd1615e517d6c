"""Segmented (discrete Kirchhoff) rod model of the twisted beam, built with MuJoCo's ``MjSpec``.

The beam (length L, rectangular section w × t) is cut into N rigid bodies joined by N elastic joints, each a set of
three hinges: torsion about the rod axis (GJ/w_k), bending about the section's weak axis (EI_weak/w_k) and about
its strong axis (EI_strong/w_k), where w_k is the length of material joint k stands for. Joint placement:

- ``midpoint`` (``rodN``): s_k = (k + ½)·L/N, w_k = L/N — a joint carries the compliance from s_k − ℓ/2 to
  s_k + ℓ/2, so a half segment stays on the clamp and the last body is a half segment ending at the tip; the
  static tip deflection under a tip load is PL³/3EI · (1 − 1/4N²). Converges as N grows (``rod40`` is the
  reference of the fidelity ladder).
- ``gauss`` (``rodNg``): the N Gauss–Legendre nodes and weights on [0, L] — exact static compliance for
  polynomial moment distributions up to degree 2N − 1, so 3 joints come close to the continuum.

The rod is pre-twisted: the section angle grows linearly, θ(s) = φ·s/L; body k is turned about the axis by the
twist accumulated up to it, and each joint's hinge axes follow the section at the joint. The sign of φ sets the
chirality (φ > 0: right-handed). A pre-twisted strip is stiffer in torsion than a straight one: twisting it
stretches its edges along their helices, which adds the extension–twist ("trapeze") term E·κ²·t·w⁵/180, κ = φ/L,
to the Saint-Venant GJ (``RodParams.torsion_gj``; ×1.9 for 90° over 50 mm of a 20 × 3 mm strip). Damping is stiffness proportional, b = β·k per hinge. Each segment carries the
mass and rotary inertia of its piece of the strip (``RodParams.segment_inertia``); by default the parameter
set's weighed mass (5.17 g) is spread along the length, as the paper's PRB3 does.

Frame: as every model of :mod:`beambench.sim.models.beam`: the rod leaves the clamp along +y, with the width along z
and the thickness along x at the root (weak bending toward x, the stage's direction of travel).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import mujoco
import numpy as np

from beambench.common.types import Floats
from beambench.sim.models.beam import BeamModel, BeamSites, qinv, qmul, quat_x
from beambench.sim.models.families import ROD, beam_builder
from beambench.sim.models.names import ROD_NAME
from beambench.sim.models.params import BeamParams, Material


@dataclass(frozen=True)
class RodParams:
    """Geometry and material of a segmented rod (SI units)."""

    n_segments: int = 10
    length: float = 0.050
    width: float = 0.020
    thickness: float = 0.003
    youngs_modulus: float = 26e6
    poisson: float = 0.45
    density: float = 1210.0
    beta: float = 6e-4  # s, stiffness-proportional damping: b = beta * k
    rotary_inertia: bool = True  # False: Euler–Bernoulli idealisation (no section rotary inertia), for checks
    dofs: str = "twist,weak,strong"  # hinges per joint (dropping "strong" makes the rod rigid in strong bending)
    nodes: str = "midpoint"  # joint placement: "midpoint" (s_k = (k + ½)L/N) or "gauss" (Gauss–Legendre)
    trapeze: bool = True  # add the pre-twist's extension–twist term to the torsion stiffness (torsion_gj)

    @classmethod
    def from_beam(
        cls, beam: BeamParams, n_segments: int = 10, nodes: str = "midpoint", mass: str = "measured"
    ) -> RodParams:
        """Rod with the geometry, material and damping (``beta``) of a parameter set.

        ``mass="measured"`` spreads the set's ``mass`` (the weighed prototype, 5.17 g, as the paper's PRB3
        does) uniformly along the rod — an effective density of mass/(w·t·L); ``mass="density"`` uses the
        material density (1210 kg/m³ gives 3.63 g for 50 × 20 × 3 mm).
        """
        m: Material = beam.material
        density = m.density if mass == "density" else beam.mass / (beam.width * beam.thickness * beam.length)
        return cls(
            n_segments=n_segments,
            length=beam.length,
            width=beam.width,
            thickness=beam.thickness,
            youngs_modulus=m.youngs_modulus,
            poisson=m.poisson,
            density=density,
            beta=beam.beta,
            nodes=nodes,
        )

    @property
    def area(self) -> float:
        return self.width * self.thickness

    @property
    def mass(self) -> float:
        return self.density * self.area * self.length

    @property
    def shear_modulus(self) -> float:
        return self.youngs_modulus / (2.0 * (1.0 + self.poisson))

    @property
    def ei_weak(self) -> float:
        """Bending stiffness about the width axis (load along the thickness), N·m²."""
        return self.youngs_modulus * self.width * self.thickness**3 / 12.0

    @property
    def ei_strong(self) -> float:
        """Bending stiffness about the thickness axis (load along the width), N·m²."""
        return self.youngs_modulus * self.thickness * self.width**3 / 12.0

    @property
    def gj(self) -> float:
        """Saint-Venant torsional stiffness of the rectangle (series solution for J), N·m²."""
        a, b = max(self.width, self.thickness), min(self.width, self.thickness)
        r = b / a
        k = 1.0 / 3.0 - 0.21 * r * (1.0 - r**4 / 12.0)  # Roark's formula, < 0.5 % error
        return self.shear_modulus * k * a * b**3

    def trapeze_gj(self, twist_deg: float) -> float:
        """Extension–twist ("trapeze") stiffness of the pre-twisted strip, N·m²: E·κ²·t·w⁵/180 with κ = φ/L.

        Twisting a strip that is already twisted at rate κ stretches its fibres at distance y from the axis by
        κ·y²·dθ/ds; their axial stress integrates to this extra torque (thin strip, w ≫ t, small added twist).
        """
        kappa = math.radians(twist_deg) / self.length
        return self.youngs_modulus * kappa**2 * self.thickness * self.width**5 / 180.0

    def torsion_gj(self, twist_deg: float) -> float:
        """Torsion stiffness of the pre-twisted strip, N·m²: Saint-Venant GJ plus the trapeze term (if on)."""
        return self.gj + (self.trapeze_gj(twist_deg) if self.trapeze else 0.0)

    def first_frequency(self, axis: str = "weak") -> float:
        """Euler–Bernoulli first cantilever frequency, Hz: 1.875²/2π · √(EI/ρAL⁴)."""
        ei = self.ei_weak if axis == "weak" else self.ei_strong
        return 1.875104**2 / (2 * math.pi) * math.sqrt(ei / (self.density * self.area * self.length**4))

    def segment_inertia(self, seg: float) -> tuple[float, list[float]]:
        """Mass and principal inertia (torsion, weak bending, strong bending) of a segment of length ``seg``."""
        m = self.density * self.area * seg
        w2, t2, s2 = self.width**2, self.thickness**2, seg**2
        if self.rotary_inertia:
            return m, [m * (w2 + t2) / 12, m * (s2 + t2) / 12, m * (s2 + w2) / 12]
        # Euler–Bernoulli idealisation: no rotary inertia of the section; torsional inertia cut to the least a
        # rigid body allows (A + B >= C). Only for checks of bending against beam theory.
        return m, [m * s2 / 6, m * s2 / 12, m * s2 / 12]

    def joint_layout(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions s_k along the rod and the length of material w_k each joint stands for (Σw = L).

        ``midpoint``: s_k = (k + ½)·L/N, w_k = L/N. ``gauss``: the N Gauss–Legendre nodes and weights on [0, L],
        which make the compliance integral ∫ M(s)·m(s)/EI ds exact for polynomial moments up to degree
        2N − 1 (tip deflection and rotation under tip or uniform loads are exact from N = 2).
        """
        n, L = int(self.n_segments), self.length
        if self.nodes == "midpoint":
            return (np.arange(n) + 0.5) * L / n, np.full(n, L / n)
        if self.nodes == "gauss":
            x, w = np.polynomial.legendre.leggauss(n)
            return (x + 1) * L / 2, w * L / 2
        raise ValueError(f"nodes = {self.nodes!r}: 'midpoint' or 'gauss'")


# the rod is built along its own +x (width y, thickness z); this maps it onto the beam convention of
# beam.py: axis +y, width z, thickness x (a rotation of 120° about (1, 1, 1): x→y, y→z, z→x)
_ROD_TO_CLAMP = (0.5, 0.5, 0.5, 0.5)


def add_rod(
    parent: mujoco.MjsBody,
    rod: RodParams,
    twist_deg: float = 90.0,
    pos: Floats = (0.0, 0.0, 0.0),
    quat: Floats = (1.0, 0.0, 0.0, 0.0),
    prefix: str = "beam_",
    rgba: Floats = (0.9, 0.55, 0.1, 1.0),
) -> BeamSites:
    """Attach a pre-twisted segmented rod to ``parent`` with its clamp at ``pos``/``quat`` (parent frame).

    Same convention as :func:`beambench.sim.models.beam.add_beam`: the rod leaves the clamp along +y, with the width
    along z and the thickness along x at the root; ``twist_deg`` is the total twist φ, its sign the chirality.
    The tip body is aligned with the clamp frame in the natural shape; the root site sits at the clamp point on
    the first moving segment.
    """
    n = int(rod.n_segments)
    if n < 1:
        raise ValueError(f"n_segments = {n}: must be >= 1")
    nodes, weights = rod.joint_layout()
    phi = math.radians(twist_deg)
    gj = rod.torsion_gj(twist_deg)
    hw, ht = rod.width / 2, rod.thickness / 2
    box = dict(type=mujoco.mjtGeom.mjGEOM_BOX, contype=0, conaffinity=0, rgba=list(rgba))
    frame_quat = qmul(quat, _ROD_TO_CLAMP)  # rod frame in the parent
    frame = parent.add_frame(pos=list(pos), quat=list(frame_quat))

    # the piece [0, s_0] before the first joint rides on the clamp (its mass goes to the parent)
    s0 = float(nodes[0])
    clamp = parent.add_geom(
        name=f"{prefix}clamp", size=[s0 / 2, hw, ht], pos=[s0 / 2, 0, 0], density=rod.density, **box
    )
    clamp.set_frame(frame)

    bodies: list[str] = []
    joints: list[str] = []
    body = parent
    ends = np.append(nodes[1:], rod.length)
    for k in range(n):
        seg = float(ends[k] - nodes[k])
        dphi = phi * weights[k] / rod.length  # the twist of the material this joint stands for
        offset = s0 if k == 0 else float(nodes[k] - nodes[k - 1])
        b = body.add_body(name=f"{prefix}s{k}", pos=[offset, 0, 0], quat=list(quat_x(dphi)))
        if k == 0:
            b.set_frame(frame)
            first = b
        # hinge axes in the child frame, turned back by dphi/2 onto the section at the joint
        c, s = math.cos(dphi / 2), math.sin(dphi / 2)
        w = float(weights[k])
        axes = (
            ("twist", [1.0, 0.0, 0.0], gj / w),
            ("weak", [0.0, c, -s], rod.ei_weak / w),
            ("strong", [0.0, s, c], rod.ei_strong / w),
        )
        for tag, axis, kk in axes:
            if tag not in rod.dofs.split(","):
                continue
            name = f"{prefix}j{k}_{tag}"
            b.add_joint(
                name=name,
                type=mujoco.mjtJoint.mjJNT_HINGE,
                axis=axis,
                stiffness=[kk, 0.0, 0.0],
                damping=[rod.beta * kk, 0.0, 0.0],
            )
            joints.append(name)
        mass, inertia = rod.segment_inertia(seg)
        b.explicitinertial = True
        b.mass, b.ipos, b.iquat, b.inertia = mass, [seg / 2, 0, 0], [1, 0, 0, 0], inertia
        b.add_geom(name=f"{prefix}g{k}", size=[seg / 2, hw, ht], pos=[seg / 2, 0, 0], density=0.0, mass=0.0, **box)
        bodies.append(b.name)
        body = b
    # root site: at the clamp point on the first moving segment, aligned with the clamp frame at rest
    dphi0 = phi * weights[0] / rod.length
    root_quat = qmul(quat_x(-dphi0), qinv(_ROD_TO_CLAMP))
    first.add_site(name=f"{prefix}root", pos=[-s0, 0, 0], quat=list(root_quat), size=[0.002, 0, 0])
    # tip body: at the tip, aligned with the clamp frame in the natural shape
    tip_quat = qmul(quat_x(-phi), qinv(_ROD_TO_CLAMP))
    tip = body.add_body(name=f"{prefix}tip", pos=[float(rod.length - nodes[-1]), 0, 0], quat=list(tip_quat))
    tip.add_site(name=f"{prefix}tip_site", size=[0.002, 0, 0])
    bodies.append(tip.name)
    return BeamSites(f"{prefix}root", f"{prefix}tip_site", tip.name, tuple(joints), tuple(bodies))


class RodModel(BeamModel):
    """The segmented rod as a :class:`~beambench.sim.models.beam.BeamModel` (``sim.model: rod10``, ``rod3g`` …).

    Geometry and material come from the parameter set (``params.material``); the joint springs from the
    section, not from ``k``/``b`` (those belong to PRB3).
    """

    name = "rod"

    def __init__(
        self, params: BeamParams, n_segments: int = 10, nodes: str = "midpoint", dofs: str = "twist,weak,strong"
    ) -> None:
        super().__init__(params)
        self.rod = replace(RodParams.from_beam(params, n_segments=n_segments, nodes=nodes), dofs=dofs)
        self.name = f"rod{n_segments}" + ("g" if nodes == "gauss" else "") + ("s" if "strong" not in dofs else "")

    def build(
        self,
        parent: mujoco.MjsBody,
        twist_deg: float,
        pos: Floats = (0, 0, 0),
        quat: Floats = (1, 0, 0, 0),
        prefix: str = "beam_",
    ) -> BeamSites:
        return add_rod(parent, self.rod, twist_deg, pos, quat, prefix)

    def torsion_stiffness(self) -> float:
        """Saint-Venant GJ plus the trapeze term at the parameter set's twist, over L."""
        return self.rod.torsion_gj(self.params.twist_deg) / self.rod.length

    def describe(self) -> dict[str, Any]:
        r = self.rod
        return {
            "model": self.name,
            "params": self.params.to_dict(),
            "rod": {
                **asdict(r),
                "ei_weak": r.ei_weak,
                "ei_strong": r.ei_strong,
                "gj": r.gj,
                "gj_twisted": r.torsion_gj(self.params.twist_deg),
                "mass": r.mass,
            },
        }


@beam_builder(ROD)
def make_rod_model(name: str, params: BeamParams) -> RodModel:
    """A rod by name: ``rodN`` — N joints at the segment midpoints; ``rodNg`` — at the N Gauss–Legendre nodes
    (the same cost, far closer to the continuum for small N); a trailing ``s`` (``rod3gs``) makes a *strip*
    without strong-axis bending hinges (EI_strong/EI_weak = 44: 2 hinges per joint, cheaper, and no
    high strong-bending modes). Geometry, material, mass and damping come from ``params``."""
    m = ROD_NAME.fullmatch(name)
    if not m or int(m.group(1)) < 1:
        raise ValueError(f"sim.model = {name!r}: a segmented rod is rodN, rodNg or rodNgs with N >= 1, e.g. rod10")
    return RodModel(
        params,
        n_segments=int(m.group(1)),
        nodes="gauss" if m.group(2) else "midpoint",
        dofs="twist,weak" if m.group(3) else "twist,weak,strong",
    )


def natural_frequencies(
    model: mujoco.MjModel, qpos: np.ndarray | None = None, eps: float = 1e-7, modes: bool = False
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Undamped natural frequencies (Hz, ascending) of the model linearised at ``qpos`` (default: its rest pose),
    and with ``modes=True`` also the mode shapes (columns, [nv, nv], M-normalised).

    K = −∂(qfrc_passive − qfrc_bias)/∂q by central differences at zero velocity, M from ``mj_fullM``; solves
    K v = ω² M v. Springs, gravity and geometric stiffness are all included; damping is not.
    """
    from scipy.linalg import eigh

    data = mujoco.MjData(model)
    q0 = model.qpos0.copy() if qpos is None else np.asarray(qpos, float)
    nv = model.nv
    if model.nq != nv:
        raise ValueError("natural_frequencies: only models with hinge/slide joints (nq == nv)")

    def force(q: np.ndarray) -> np.ndarray:
        data.qpos[:] = q
        data.qvel[:] = 0
        mujoco.mj_forward(model, data)
        return data.qfrc_passive - data.qfrc_bias

    K = np.empty((nv, nv))
    for i in range(nv):
        dq = np.zeros(nv)
        dq[i] = eps
        K[:, i] = -(force(q0 + dq) - force(q0 - dq)) / (2 * eps)
    K = 0.5 * (K + K.T)
    force(q0)
    M = np.empty((nv, nv))
    mujoco.mj_fullM(model, data, M)
    w2, vecs = eigh(K, M)
    f = np.sqrt(np.clip(w2, 0, None)) / (2 * np.pi)
    return (f, vecs) if modes else f
