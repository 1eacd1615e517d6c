"""The scene registry, in the manner of dm_control's suite: each scene module registers how it is built.

What a scene *is* (name, markers, options, flags) is its :class:`~beambench.acquisition.protocol.scenes.SceneInfo`, declared
in :mod:`beambench.acquisition.protocol.scenes` so the protocol model can read it without MuJoCo. Here a scene module adds
how it is built from its slice of the protocol (a :class:`SceneConfig`)::

    @register(CONTACT)
    def build(cfg: SceneConfig) -> ContactRigSim: ...

The package (:mod:`beambench.sim.scenes`) imports every scene module, so :func:`get` knows them all.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from beambench.acquisition.protocol.scenes import SceneInfo, scene_info
from beambench.sim.models.beam import BeamModel
from beambench.sim.protocol_slice import SimSlice
from beambench.sim.scenes.drive import DrivenScene

__all__ = ["Scene", "SceneConfig", "get", "register"]


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


_REGISTRY: dict[str, Scene] = {}


def register(info: SceneInfo) -> Callable[[Builder], Builder]:
    """Decorator: ``build`` makes the scene ``info`` describes (once per scene)."""

    def add(build: Builder) -> Builder:
        if info.name in _REGISTRY:
            raise ValueError(f"scene {info.name!r} is registered twice")
        _REGISTRY[info.name] = Scene(info, build)
        return build

    return add


def get(name: str) -> Scene:
    """The registered scene ``name`` (KeyError naming the known ones)."""
    scene_info(name)  # an undeclared name: the catalogue's KeyError
    try:
        return _REGISTRY[name]
    except KeyError:
        raise KeyError(f"scene {name!r} has no builder (registered: {', '.join(_REGISTRY)})") from None
