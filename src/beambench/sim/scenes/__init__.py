"""The MuJoCo scenes, one module each, collected into one registry (:mod:`.registry`).

Importing the package imports every module in it, and each scene module registers its builder
(``@register(INFO)``); the sim backend builds a protocol's scene with ``get(sim.scene).build(config)``. Adding a
scene: its :class:`~beambench.acquisition.protocol.scenes.SceneInfo` in :mod:`beambench.acquisition.protocol.scenes` and its module
here (docs/extending.md).
"""

import importlib
import pkgutil

from beambench.sim.scenes.registry import Scene, SceneConfig, get, register

for _module in pkgutil.iter_modules(__path__):  # each scene module registers itself on import
    importlib.import_module(f"{__name__}.{_module.name}")

__all__ = ["Scene", "SceneConfig", "get", "register"]
