"""Where a command will write, checked before it writes anything: a read-only folder or file is one line up
front, not a traceback after half the outputs were written (``analyze`` once stored ``/processing`` in the session,
then failed on the report folder).

No command writes through a symbolic link: an output folder or file of a command (a report folder, a fit folder, a
calibration, a parameter set, a table) that is a link — dangling or not — is a taken name, as a session file's is
for ``run``; so is a link inside an output folder the command fills. A link planted where a default output goes
cannot redirect what a command writes."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["output_file_problem", "output_folder_problem", "unwritable_file", "unwritable_folder"]


def unwritable_folder(folder: Path) -> str | None:
    """Why files cannot be written into ``folder`` (created if missing), or None. Probes for real (a temporary
    file or folder, removed at once), so a read-only mount is found for root too; nothing is left behind."""
    folder = Path(folder)
    probe_in = folder
    while not probe_in.exists():
        if probe_in.parent == probe_in:
            return f"{folder}: no folder on the way exists"
        probe_in = probe_in.parent
    if not probe_in.is_dir():
        return f"{probe_in}: not a folder"
    try:
        if probe_in == folder:
            fd, name = tempfile.mkstemp(prefix=".beambench-probe-", dir=folder)
            os.close(fd)
            os.unlink(name)
        else:
            os.rmdir(tempfile.mkdtemp(prefix=".beambench-probe-", dir=probe_in))
    except OSError as exc:
        return f"{probe_in}: cannot write there ({exc.strerror or exc})"
    return None


def unwritable_file(path: Path) -> str | None:
    """Why the existing file ``path`` cannot be written in place, or None (opened for writing, nothing written)."""
    try:
        os.close(os.open(path, os.O_WRONLY))
    except OSError as exc:
        return f"{path}: cannot write into it ({exc.strerror or exc})"
    return None


def _link(path: Path) -> str:
    return f"{path}: a symbolic link; beambench never writes through one (remove it or choose another name)"


def output_folder_problem(folder: Path, names: tuple[str, ...] | None = None) -> str | None:
    """Why ``folder`` cannot be a command's output folder, or None: a symbolic link, not a folder, a folder that
    cannot take files, or a link among the entries the command writes into it (``names``; None: any entry, for a
    folder whose every file is the command's own, a report's)."""
    folder = Path(folder)
    if folder.is_symlink():
        return _link(folder)
    if folder.exists() and not folder.is_dir():
        return f"{folder}: not a folder"
    if folder.is_dir():
        try:
            entries = [folder / n for n in names] if names is not None else list(folder.iterdir())
        except OSError as exc:
            return f"{folder}: cannot list it ({exc.strerror or exc})"
        link = next((p for p in entries if p.is_symlink()), None)
        if link is not None:
            return _link(link)
    return unwritable_folder(folder)


def output_file_problem(path: Path) -> str | None:
    """Why a command cannot write the file ``path`` (a new one, or one it replaces), or None: a symbolic link,
    not a regular file (a folder, a device such as ``/dev/full``, a FIFO), a file it cannot write, or a folder
    that cannot take it. Probed for real and nothing left behind, so it runs before any work."""
    path = Path(path)
    if path.is_symlink():
        return _link(path)
    if path.exists():
        if not path.is_file():
            return f"{path}: not a regular file (a folder, a device or a pipe)"
        return unwritable_file(path)
    return unwritable_folder(path.parent)
