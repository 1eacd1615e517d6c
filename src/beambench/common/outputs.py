"""Where a command will write, checked before it writes anything: a read-only folder or file is one line up
front, not a traceback after half the outputs were written (``analyze`` once stored ``/processing`` in the session,
then failed on the report folder)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["unwritable_file", "unwritable_folder"]


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
