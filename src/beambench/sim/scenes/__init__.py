"""The MuJoCo scenes, one module each, collected into one registry (:mod:`.registry`).

Importing the package imports every scene module, and each registers its builder (``@register(INFO)``); the sim
backend builds a protocol's scene with ``get(protocol.rig).build(config)``. Adding a scene: its
:class:`~beambench.acquisition.scenes.SceneInfo` in :mod:`beambench.acquisition.scenes`, its module here, and
its name in the import below.
"""

from beambench.sim.scenes import contact_rig, release, walker  # noqa: F401  (each registers itself)
from beambench.sim.scenes.registry import Scene, SceneConfig, get, register

__all__ = ["Scene", "SceneConfig", "get", "register"]
