"""Where beambench finds the data it ships and where it writes the user's own files.

The one place that knows the layout; every module asks here instead of walking up from its own file.

- Shipped data (parameter sets and measured tables in ``sim_backend``, ``calibration``, ``protocols``) lives in
  the package as ``beambench/data/<name>/`` and is found with :mod:`importlib.resources`, so an installed wheel
  works from any folder. In a checkout those folders are symlinks to the top-level ``sim_backend/``,
  ``calibration/`` and ``protocols/``, which stay the place developers edit.
- The user's own files (load-cell calibrations, fitted parameter sets) go to a per-user folder, never into the
  checkout or the installed package: ``$BEAMBENCH_USER_DIR`` if set, else platformdirs' user data folder
  (``~/.local/share/beambench`` on Linux, ``~/Library/Application Support/beambench`` on macOS,
  ``%LOCALAPPDATA%\\beambench`` on Windows).
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path
from typing import Literal, get_args

ShippedName = Literal["sim_backend", "calibration", "protocols"]
SHIPPED: tuple[str, ...] = get_args(ShippedName)
USER_DIR_ENV = "BEAMBENCH_USER_DIR"


def shipped_dir(name: ShippedName) -> Path:
    """The shipped folder ``name`` inside the installed package (read-only: never write here)."""
    if name not in SHIPPED:
        raise ValueError(f"{name!r}: not a shipped folder (known: {', '.join(SHIPPED)})")
    # The package is installed as files on disk (wheel or editable), so the traversable is a real path.
    return Path(str(resources.files("beambench") / "data" / name))


def user_dir(name: str = "") -> Path:
    """The per-user folder for beambench's outputs (``$BEAMBENCH_USER_DIR`` or platformdirs' user data folder),
    or its subfolder ``name``. Not created here: writers create it when they first write."""
    env = os.environ.get(USER_DIR_ENV)
    if env:
        root = Path(env).expanduser()
    else:
        import platformdirs

        root = platformdirs.user_data_path("beambench", appauthor=False)
    return root / name if name else root


def search_path(name: ShippedName) -> list[Path]:
    """Folders searched for named files of kind ``name``, first match wins: the user's, then the package's."""
    return [user_dir(name), shipped_dir(name)]


def find_file(name: ShippedName, filename: str) -> Path | None:
    """The first ``filename`` in :func:`search_path` (``name``), or None."""
    for folder in search_path(name):
        if (folder / filename).is_file():
            return folder / filename
    return None


def shipped_protocols() -> dict[str, Path]:
    """The protocols shipped with the package, by name (``contact_sweep`` → …/protocols/contact_sweep.yaml)."""
    return {p.stem: p for p in sorted(shipped_dir("protocols").glob("*.yaml"))}
