"""Start the native Rerun viewer listening on loopback only (``rr.spawn`` binds every interface, 0.0.0.0).

:func:`spawn_viewer` does what ``rr.spawn`` does (reuse a viewer already listening on the port, else start one
detached and wait until it listens) with ``--bind 127.0.0.1``: the session's data never leave the machine unless a
user starts a viewer of their own elsewhere. A missing viewer binary or a viewer that cannot start is one line
(:class:`ViewerStartError`).
"""

from __future__ import annotations

import importlib.util
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

from beambench.common.errors import BeambenchError
from beambench.common.text import printable

__all__ = ["LOOPBACK", "VIEWER_PORT", "ViewerStartError", "rerun_binary", "spawn_viewer", "viewer_reason", "viewer_url"]

LOOPBACK = "127.0.0.1"
VIEWER_PORT = 9876  # Rerun's default: `--rerun connect` and a viewer started by hand find it there
START_TIMEOUT_S = 30.0  # a cold start on a loaded machine (Vulkan initialisation) takes seconds


class ViewerStartError(BeambenchError, RuntimeError):
    """The viewer binary is missing or the viewer did not start listening (one line)."""


def rerun_binary() -> Path | None:
    """The native ``rerun`` executable shipped with the rerun-sdk wheel (package ``rerun_cli``), else on PATH."""
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        shipped = Path(spec.origin).with_name("rerun")
        if shipped.is_file():
            return shipped
    found = shutil.which("rerun")
    return Path(found) if found else None


def viewer_url(port: int = VIEWER_PORT) -> str:
    """The gRPC address a recording stream connects to."""
    return f"rerun+http://{LOOPBACK}:{port}/proxy"


def _listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex((LOOPBACK, port)) == 0


def spawn_viewer(
    port: int = VIEWER_PORT, memory_limit: str = "75%", server_memory_limit: str = "1GiB"
) -> subprocess.Popen[bytes] | None:
    """Start a viewer on ``127.0.0.1:port`` unless one already listens there; returns the new process (None when
    one was already running). Waits until it listens (or exits, or :data:`START_TIMEOUT_S` passes)."""
    if _listening(port):
        return None
    binary = rerun_binary()
    if binary is None:
        raise ViewerStartError(
            "the Rerun viewer binary was not found (it ships with the rerun-sdk wheel; pip install rerun-sdk)"
        )
    args = [str(binary), "--bind", LOOPBACK, "--port", str(port)]
    args += ["--memory-limit", memory_limit, "--server-memory-limit", server_memory_limit]
    with tempfile.TemporaryFile() as log:  # its own lines, said if it exits at start (the file is unlinked: the
        # viewer keeps writing its few warnings there, the space freed when it exits)
        proc = subprocess.Popen(  # detached: the viewer outlives the run, as with rr.spawn
            args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=log, start_new_session=True
        )
        deadline = time.monotonic() + START_TIMEOUT_S
        while not _listening(port):
            code = proc.poll()
            if code is not None:
                log.seek(0)
                said = viewer_reason(log.read())
                raise ViewerStartError(
                    f"the Rerun viewer exited at start (status {code}{': ' + said if said else '; no display?'})"
                )
            if time.monotonic() > deadline:
                raise ViewerStartError(
                    f"the Rerun viewer did not listen on {LOOPBACK}:{port} within {START_TIMEOUT_S:g} s"
                )
            time.sleep(0.05)  # polling a condition with a deadline, not a fixed wait
    return proc


def viewer_reason(output: bytes) -> str:
    """What a viewer that failed said: its panic or ERROR line, else its last line (escape sequences removed, at
    most its last 300 characters); "" when it said nothing."""
    raw_lines = output.decode("utf-8", "replace").splitlines()
    lines = [line for line in (printable(raw, limit=None).strip() for raw in raw_lines) if line]
    panics = [line for line in lines if "panicked" in line or " ERROR " in line]
    return (panics or lines or [""])[-1][-300:]
