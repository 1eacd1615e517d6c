"""Beam models built into a MuJoCo scene with the ``MjSpec`` editing API.

Convention (every model): the beam leaves its clamp along the clamp frame's **+y** axis; at the root its
cross-section has the width along **z** and the thickness along **x** (so the weak bending direction at the
root is x). The section rotates about the beam axis by ``twist_deg`` from root to tip; the sign of the twist
is the chirality (φ > 0 right-handed). φ → −φ mirrors the beam across the clamp's y–z plane.

Use :func:`add_beam` with a model from :func:`beambench.sim.models.registry.make_beam_model`. A new model subclasses :class:`BeamModel` and
implements :meth:`BeamModel.build` (as the segmented rod of :mod:`beambench.sim.models.rod` does).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from beambench.common.types import Floats
from beambench.sim.models import families
from beambench.sim.models.params import BeamParams

Vec3 = Floats
Quat = Floats


@dataclass(frozen=True)
class BeamSites:
    """Names of what a builder added: attach things to ``tip_body`` (its frame is the clamp frame at rest)."""

    root_site: str  # on the first moving link at the clamp; a force sensor here gives the beam's reaction
    tip_site: str  # the beam's distal end (centre of the tip section)
    tip_body: str  # rigid body at the tip, aligned with the clamp frame in the natural (unloaded) shape
    joints: tuple[str, ...]
    bodies: tuple[str, ...]


def quat_x(angle_rad: float) -> np.ndarray:
    """Quaternion (w, x, y, z) of a rotation by ``angle_rad`` about +x."""
    return np.array([math.cos(angle_rad / 2), math.sin(angle_rad / 2), 0.0, 0.0])


def quat_y(angle_rad: float) -> np.ndarray:
    """Quaternion (w, x, y, z) of a rotation by ``angle_rad`` about +y."""
    return np.array([math.cos(angle_rad / 2), 0.0, math.sin(angle_rad / 2), 0.0])


def qmul(a: Quat, b: Quat) -> np.ndarray:
    """The quaternion product ``a ∘ b`` (b first, then a)."""
    out = np.empty(4)
    mujoco.mju_mulQuat(out, np.asarray(a, float), np.asarray(b, float))
    return out


def qinv(a: Quat) -> np.ndarray:
    """The inverse rotation of unit quaternion ``a``."""
    out = np.empty(4)
    mujoco.mju_negQuat(out, np.asarray(a, float))
    return out


class BeamModel(ABC):
    """A beam model: a parameter set plus a way of building bodies and joints from it."""

    name: str = "beam"

    def __init__(self, params: BeamParams) -> None:
        self.params = params

    @abstractmethod
    def build(self, parent: mujoco.MjsBody, twist_deg: float, pos: Vec3, quat: Quat, prefix: str) -> BeamSites:
        """Add the beam to ``parent`` with its clamp at ``pos``/``quat`` (parent frame)."""

    def describe(self) -> dict[str, Any]:
        """Model name and parameters, for the session's ``/general/identity``."""
        return {"model": self.name, "params": self.params.to_dict()}

    @abstractmethod
    def torsion_stiffness(self) -> float:
        """The whole beam's twist stiffness about its axis, tip against clamp (N·m/rad)."""

    # Shared helpers for subclasses ------------------------------------------------------------------
    def _link_geom(self, body: mujoco.MjsBody, length: float, mass: float, name: str) -> None:
        """A box of the beam's section over ``[0, length]`` along +y, visual only (no collisions)."""
        p = self.params
        body.add_geom(
            name=name,
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[p.thickness / 2, length / 2, p.width / 2],
            pos=[0, length / 2, 0],
            mass=mass,
            contype=0,
            conaffinity=0,
            rgba=[0.2, 0.5, 0.9, 1],
        )


class PRB3(BeamModel):
    """The paper's pseudo-rigid-body model: bending joints R1, R2, R3 and twist joints R4, R5.

    Layout along the beam: R1 | link1 (l1) | R4 R2 | link2 (l2) | R5 R3 | link3 (l3) | tip. Each twist joint
    carries half the total twist as rest twist (baked into the link frames, so every joint rests at 0): the
    bending axes R1, R2, R3 are the section's width direction at 0, φ/2 and φ. Link masses are m·l_k/l.
    With l1 = 0, R1, R4 and R2 share one body; with φ = 0 too, R1 and R2 coincide and are merged into one
    joint of stiffness k/2 (two equal springs in series) to keep the mass matrix regular.
    """

    name = "prb3"

    def torsion_stiffness(self) -> float:
        """R4 and R5 in series: k_twist / 2."""
        return self.params.k_twist / 2.0

    def build(
        self,
        parent: mujoco.MjsBody,
        twist_deg: float,
        pos: Vec3 = (0, 0, 0),
        quat: Quat = (1, 0, 0, 0),
        prefix: str = "beam_",
    ) -> BeamSites:
        p = self.params
        half = math.radians(twist_deg) / 2
        bend = dict(type=mujoco.mjtJoint.mjJNT_HINGE, stiffness=[p.k, 0, 0], damping=[p.b, 0, 0])
        twist = dict(
            type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0], stiffness=[p.k_twist, 0, 0], damping=[p.b_twist, 0, 0]
        )
        joints: list[str] = []
        bodies: list[str] = []

        def add_joint(body: mujoco.MjsBody, name: str, axis: Vec3 | None, spec: dict[str, Any]) -> None:
            kw = dict(spec)
            if axis is not None:
                kw["axis"] = list(axis)
            body.add_joint(name=prefix + name, **kw)
            joints.append(prefix + name)

        # R1 (section at 0°) -> optional link1 -> R4, R2 (section at φ/2) -> link2
        if p.l1 > 0:
            link1 = parent.add_body(name=prefix + "link1", pos=list(pos), quat=list(quat))
            bodies.append(link1.name)
            add_joint(link1, "R1", (0, 0, 1), bend)
            self._link_geom(link1, p.l1, p.mass * p.l1 / p.length, prefix + "geom1")
            link2 = link1.add_body(name=prefix + "link2", pos=[0, p.l1, 0], quat=list(quat_y(half)))
            first = link1
            root_quat = (1.0, 0.0, 0.0, 0.0)
        else:
            q = np.empty(4)
            mujoco.mju_mulQuat(q, np.asarray(quat, float), quat_y(half))
            link2 = parent.add_body(name=prefix + "link2", pos=list(pos), quat=list(q))
            first = link2
            root_quat = tuple(quat_y(-half))
            if abs(half) < 1e-9:  # R1 == R2: merge (series springs) to keep the model regular
                merged = dict(bend, stiffness=[p.k / 2, 0, 0], damping=[p.b / 2, 0, 0])
                add_joint(link2, "R1R2", (0, 0, 1), merged)
            else:
                add_joint(link2, "R1", (-math.sin(half), 0, math.cos(half)), bend)
        bodies.append(link2.name)
        add_joint(link2, "R4", None, twist)
        if p.l1 > 0 or abs(half) >= 1e-9:
            add_joint(link2, "R2", (0, 0, 1), bend)
        self._link_geom(link2, p.l2, p.mass * p.l2 / p.length, prefix + "geom2")
        # R5, R3 (section at φ) -> link3 -> tip
        link3 = link2.add_body(name=prefix + "link3", pos=[0, p.l2, 0], quat=list(quat_y(half)))
        bodies.append(link3.name)
        add_joint(link3, "R5", None, twist)
        add_joint(link3, "R3", (0, 0, 1), bend)
        self._link_geom(link3, p.l3, p.mass * p.l3 / p.length, prefix + "geom3")
        tip = link3.add_body(name=prefix + "tip", pos=[0, p.l3, 0], quat=list(quat_y(-2 * half)))
        bodies.append(tip.name)
        first.add_site(name=prefix + "root", quat=list(root_quat), size=[0.002, 0, 0])
        tip.add_site(name=prefix + "tip_site", size=[0.002, 0, 0])
        return BeamSites(prefix + "root", prefix + "tip_site", tip.name, tuple(joints), tuple(bodies))


@families.beam_builder(families.PRB3)
def build_prb3(name: str, params: BeamParams) -> PRB3:
    """The PRB3 model (its family has the one name)."""
    return PRB3(params)


def add_beam(
    parent: mujoco.MjsBody,
    model: BeamModel,
    twist_deg: float,
    pos: Vec3 = (0, 0, 0),
    quat: Quat = (1, 0, 0, 0),
    prefix: str = "beam_",
) -> BeamSites:
    """Attach ``model`` to ``parent`` with ``twist_deg`` of total twist (sign = chirality)."""
    return model.build(parent, twist_deg, pos, quat, prefix)
