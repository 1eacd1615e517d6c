"""The MuJoCo scenes, one module each, collected into one registry (:mod:`.registry`).

The package imports the scene modules listed below (as dm_control's suite lists its domains), and each registers
its builder (``@register(INFO)``) and, if it has one, its batched engine (``@batched(INFO)``); the sim backend
builds a protocol's scene with ``get(sim.scene).build(config)``, a sweep runs ``batch_engine(scene)``. Adding a
scene: its module here, its line in the import list below and its one-line
:class:`~beambench.acquisition.protocol.scenes.SceneInfo` declaration in :mod:`beambench.acquisition.protocol.scenes`
(docs/extending.md).
"""

from beambench.sim.scenes import (  # noqa: F401  (the scene modules: each registers itself on import)
    contact_rig,
    contact_sweep,
    free_beam,
    release,
    walker,
)
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
