"""What a session records about where it came from: software versions, git SHA, host, start time."""

from __future__ import annotations

import platform
import subprocess
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path

PACKAGES = (
    "beambench",
    "numpy",
    "h5py",
    "mujoco",
    "rerun-sdk",
    "pydantic",
    "python-can",
    "pyserial",
    "scipy",
    "pandas",
)


def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in PACKAGES:
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def git_sha() -> str:
    """The commit of the beambench checkout, with ``-dirty`` if it has changes; '' outside git."""
    here = Path(__file__).resolve().parent
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=5,
        ).stdout.strip()
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return ""


def provenance() -> dict[str, object]:
    return {
        "versions": versions(),
        "git_sha": git_sha(),
        "host": platform.node(),
        "platform": platform.platform(),
        "started_utc": datetime.now(UTC).isoformat(timespec="seconds"),
    }
