"""The scene registry, in the manner of dm_control's suite: each scene module registers how it is built.

What a scene *is* (name, markers, options, flags) is its :class:`~beambench.acquisition.protocol.scenes.SceneInfo`, declared
in :mod:`beambench.acquisition.protocol.scenes` so the protocol model can read it without MuJoCo. Here a scene module adds
how it is built from its slice of the protocol (a :class:`SceneConfig`), and, for a sweepable scene, its batched
engine (a :class:`BatchTask` in, one :class:`JobRun` of standard channels per job out)::

    @register(CONTACT)
    def build(cfg: SceneConfig) -> ContactRigSim: ...

    @batched(CONTACT)
    def run(task: BatchTask) -> list[JobRun]: ...

The package (:mod:`beambench.sim.scenes`) imports every scene module, so :func:`get` and :func:`batch_engine` know
them all. The sweep (:mod:`beambench.studies.sweep.task`) computes its metrics from the channels a run carries,
with no code per scene.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from beambench.acquisition.protocol.scenes import SceneInfo, scene_info
from beambench.common.registry import Registry
from beambench.sim.models.beam import BeamModel
from beambench.sim.protocol_slice import SimSlice
from beambench.sim.scenes.drive import DrivenScene

__all__ = [
    "BatchEngine",
    "BatchJob",
    "BatchTask",
    "ContactTrace",
    "JobRun",
    "Scene",
    "SceneConfig",
    "batch_engine",
    "batched",
    "batched_scenes",
    "get",
    "register",
]


@dataclass(frozen=True)
class SceneConfig:
    """What a scene is built from: the beam (model and parameter set resolved) and the protocol's simulation
    slice (:func:`beambench.sim.protocol_slice.sim_slice`: windows, amplitude, integrator and timestep plan,
    plate gap, thermal drift, release block)."""

    beam: BeamModel
    sim: SimSlice


Builder = Callable[[SceneConfig], DrivenScene]


@dataclass(frozen=True)
class Scene:
    """A registered scene: its description and its builder."""

    info: SceneInfo
    build: Builder


SCENES: Registry[Scene] = Registry("scene", missing="has no builder")
"""Every scene with a builder, by name, in registration order."""


def register(info: SceneInfo) -> Callable[[Builder], Builder]:
    """Decorator: ``build`` makes the scene ``info`` describes (once per scene)."""

    def add(build: Builder) -> Builder:
        SCENES.add(info.name, Scene(info, build))
        return build

    return add


def get(name: str) -> Scene:
    """The registered scene ``name`` (KeyError naming the known ones)."""
    scene_info(name)  # an undeclared name: the catalogue's KeyError
    return SCENES[name]


@dataclass(frozen=True)
class BatchJob:
    """One simulation of a batched task: the beam (overrides applied), the drive and the sweep point.

    ``group`` keys the point (jobs with one group differ only in frequency: one compiled model serves them);
    ``point`` holds every parameter of the sweep point, so a scene reads its own options (``gap_mm``)."""

    index: int
    group: str
    beam: BeamModel
    frequency_hz: float
    twist_deg: float  # signed: the point's twist times its chirality
    amplitude_m: float
    integrator: str
    timestep: float | None  # None: the scene's own choice
    point: Mapping[str, Any]


@dataclass(frozen=True)
class BatchTask:
    """Jobs simulated together, with the sweep's windows (s) and the sample interval of the returned channels."""

    jobs: tuple[BatchJob, ...]
    settle_s: float
    record_s: float
    sample_dt: float


@dataclass(frozen=True)
class ContactTrace:
    """The plate's normal force (N) and the foot's height (m) at every step ``t`` (s) of the record window."""

    t: np.ndarray
    normal: np.ndarray
    foot_z: np.ndarray


@dataclass(frozen=True)
class JobRun:
    """One job's outcome in standard channels (world frame, m, on the sample grid ``t`` in s); a channel a scene
    does not have is None. ``reason`` says why a run that is not ``ok`` failed; ``timestep_s`` is recorded when
    the scene chose it per job."""

    index: int
    ok: bool
    t: np.ndarray
    stage: np.ndarray | None = None  # the clamp's drive displacement along x [n]
    tip: np.ndarray | None = None  # the beam's tip [n, 3]
    foot: np.ndarray | None = None  # the foot [n, 3]
    contact: ContactTrace | None = None
    reason: str = ""
    timestep_s: float | None = None


BatchEngine = Callable[[BatchTask], list[JobRun]]
BATCH_ENGINES: Registry[BatchEngine] = Registry("scene", verb="given a batched engine", missing="has no batched engine")
"""The batched engine of every sweepable scene, by scene name."""


def batched(info: SceneInfo) -> Callable[[BatchEngine], BatchEngine]:
    """Decorator: ``run`` is the batched engine of the scene ``info`` describes (``info.batched``), once."""

    def add(run: BatchEngine) -> BatchEngine:
        if not info.batched:
            raise ValueError(f"{info.name} declares no batched engine")
        return BATCH_ENGINES.add(info.name, run)

    return add


def batch_engine(name: str) -> BatchEngine:
    """The batched engine of scene ``name`` (KeyError naming the scenes that have one)."""
    scene_info(name)
    return BATCH_ENGINES[name]


def batched_scenes() -> tuple[str, ...]:
    """The scenes whose module registered a batched engine."""
    return tuple(BATCH_ENGINES)
