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
import re
from importlib import resources
from pathlib import Path
from typing import Literal, get_args

from beambench.common.errors import BeambenchError

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
    """The protocols shipped with the package, by name (``contact_sweep`` → …/protocols/contact_sweep.yaml);
    not the sweep files beside them (:func:`shipped_files`)."""
    return shipped_files("protocol")


# ------------------------------------------------------------------------------------- shipped files by name
FileKind = Literal["protocol", "sweep", "targets", "params"]
FILE_KINDS: tuple[str, ...] = get_args(FileKind)
_FOLDER: dict[str, ShippedName] = {
    "protocol": "protocols",
    "sweep": "protocols",
    "targets": "calibration",
    "params": "sim_backend",
}
_WHAT = {"protocol": "protocol", "sweep": "sweep file", "targets": "targets file", "params": "parameter set"}
_USE = {"protocol": "beambench run", "sweep": "beambench sweep"}  # the commands of kinds that share a folder
_SWEEP_KEY = re.compile(r"^(scene|grid|points):", re.MULTILINE)  # a sweep file's own top-level keys


class ShippedFileError(BeambenchError):
    """A file given by path or name that is neither a file nor a shipped file of the kind asked for."""


def _kind_of(path: Path) -> str | None:
    """The kind of the shipped file ``path`` (its folder and, in protocols/, its top-level keys), or None."""
    folder = path.parent.name
    if folder == "protocols":
        return "sweep" if _SWEEP_KEY.search(path.read_text(errors="replace")) else "protocol"
    if folder == "calibration":
        return "targets" if path.stem.endswith("_targets") else None
    if folder == "sim_backend":
        return "params" if path.suffix == ".yaml" else None
    return None


def shipped_files(kind: FileKind) -> dict[str, Path]:
    """The shipped files of ``kind`` by name, sorted (``sweep`` → ``{"chirality_sweep": …, "twist_sweep": …}``;
    ``params`` → ``{"prb3_paper": …}``, the set ``paper`` of model ``prb3``)."""
    if kind not in FILE_KINDS:
        raise ValueError(f"{kind!r}: not a kind of shipped file (known: {', '.join(FILE_KINDS)})")
    files = sorted(shipped_dir(_FOLDER[kind]).glob("*.yaml"))
    return {p.stem: p for p in files if _kind_of(p) == kind}


def resolve_file(kind: FileKind, given: str | Path) -> Path:
    """The file meant by ``given``: itself if it is a file; else the shipped file of ``kind`` named by it, as a
    name (``twist_sweep``), a file name (``twist_sweep.yaml``) or its shipped relative path
    (``protocols/twist_sweep.yaml``, ``calibration/paper_contact_targets.yaml``), from any folder and any install.

    Raises :class:`ShippedFileError` (one line) naming what is shipped of that kind, and the command that takes
    ``given`` when it is a shipped file of another kind.
    """
    path = Path(given)
    if path.is_file():
        return path
    shipped = shipped_files(kind)
    parts = path.parts
    name = path.name.removesuffix(".yaml").removesuffix(".yml")
    in_folder = len(parts) == 1 or (len(parts) == 2 and parts[0] == _FOLDER[kind])
    if in_folder and path.suffix in ("", ".yaml", ".yml") and name in shipped:
        return shipped[name]
    what = _WHAT[kind]
    if in_folder:
        for other in FILE_KINDS:
            if other != kind and _FOLDER[other] == _FOLDER[kind] and name in shipped_files(other):  # type: ignore[arg-type]
                hint = f" (use it with `{_USE[other]} {name}`)" if other in _USE else ""
                raise ShippedFileError(f"{given}: a shipped {_WHAT[other]}, not a {what}{hint}")
    names = ", ".join(shipped) or "none"
    raise ShippedFileError(f"{given}: no such {what}, nor a shipped one of that name (shipped: {names})")


def shipped_names(kind: FileKind) -> str:
    """The shipped files of ``kind`` as a comma-separated list of names, for help texts."""
    return ", ".join(shipped_files(kind))
