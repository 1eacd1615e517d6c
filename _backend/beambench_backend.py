"""beambench's build backend: setuptools, building in a temporary folder.

``pip install .`` builds in the source folder: plain setuptools leaves ``build/`` and ``src/beambench.egg-info``
in the checkout and packs whatever an earlier build left in ``build/lib`` (a module since moved or deleted) into
the next wheel. Here ``build`` and ``egg_info`` work in a fresh temporary folder (through ``DIST_EXTRA_CONFIG``,
an extra distutils config file), so a wheel holds exactly the current sources and the checkout stays clean.
Editable installs (``pip install -e .``) are plain setuptools.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator

from setuptools import build_meta as _setuptools
from setuptools.build_meta import *  # noqa: F403  (the hooks not wrapped below, e.g. build_editable)


@contextlib.contextmanager
def _out_of_tree() -> Iterator[None]:
    with tempfile.TemporaryDirectory(prefix="beambench-build-") as tmp:
        cfg = os.path.join(tmp, "out_of_tree.cfg")
        with open(cfg, "w", encoding="utf-8") as f:
            f.write(f"[build]\nbuild_base = {os.path.join(tmp, 'build')}\n[egg_info]\negg_base = {tmp}\n")
        old = os.environ.get("DIST_EXTRA_CONFIG")
        os.environ["DIST_EXTRA_CONFIG"] = cfg
        try:
            yield
        finally:
            if old is None:
                os.environ.pop("DIST_EXTRA_CONFIG", None)
            else:
                os.environ["DIST_EXTRA_CONFIG"] = old


def prepare_metadata_for_build_wheel(metadata_directory: str, config_settings: dict | None = None) -> str:
    with _out_of_tree():
        return _setuptools.prepare_metadata_for_build_wheel(metadata_directory, config_settings)


def build_wheel(
    wheel_directory: str, config_settings: dict | None = None, metadata_directory: str | None = None
) -> str:
    with _out_of_tree():
        return _setuptools.build_wheel(wheel_directory, config_settings, metadata_directory)


def build_sdist(sdist_directory: str, config_settings: dict | None = None) -> str:
    with _out_of_tree():
        return _setuptools.build_sdist(sdist_directory, config_settings)


def get_requires_for_build_wheel(config_settings: dict | None = None) -> list[str]:
    with _out_of_tree():
        return _setuptools.get_requires_for_build_wheel(config_settings)


def get_requires_for_build_sdist(config_settings: dict | None = None) -> list[str]:
    with _out_of_tree():
        return _setuptools.get_requires_for_build_sdist(config_settings)
