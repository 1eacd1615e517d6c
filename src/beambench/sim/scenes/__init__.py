"""The MuJoCo scenes, one module each, collected into one registry (:mod:`.registry`).

Importing the package imports every module in it, and each scene module registers its builder
(``@register(INFO)``) and, if it has one, its batched engine (``@batched(INFO)``); the sim backend builds a
protocol's scene with ``get(sim.scene).build(config)``, a sweep runs ``batch_engine(scene)``. Adding a scene: its
module here and its one-line :class:`~beambench.acquisition.protocol.scenes.SceneInfo` declaration in
:mod:`beambench.acquisition.protocol.scenes` (docs/extending.md).
"""

import importlib
import pkgutil

from beambench.sim.scenes.registry import (
    BatchJob,
    BatchTask,
    ContactTrace,
    JobRun,
    Scene,
    SceneConfig,
    batch_engine,
    batched,
    batched_scenes,
    get,
    register,
)

for _module in pkgutil.iter_modules(__path__):  # each scene module registers itself on import
    importlib.import_module(f"{__name__}.{_module.name}")

__all__ = [
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
