"""A copy of the installed package that a test changes as docs/extending.md tells a contributor to, and the command
line run on that copy (the extension tests: a scene, a simulated stream, a device stream). A copy, because the
registries are process-wide and the package folder is no place for test output."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import beambench


def copy_package(src: Path) -> Path:
    """``src/beambench``: a copy of the installed package (its data links followed, no byte code)."""
    pkg = src / "beambench"
    shutil.copytree(Path(beambench.__file__).parent, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    return pkg


def apply_hunk(text: str, hunk: list[str]) -> str:
    """``text`` with one diff hunk applied (its context must occur exactly once)."""
    before = "".join(line[1:] + "\n" for line in hunk if line[:1] in (" ", "-"))
    after = "".join(line[1:] + "\n" for line in hunk if line[:1] in (" ", "+"))
    assert text.count(before) == 1, f"the hunk's context is not in the file once:\n{before}"
    return text.replace(before, after)


def run_copy(src: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``python -m beambench ARGS`` on the copy in ``src`` (its worker and peer processes inherit the path, so they
    import the copy too)."""
    env = {**os.environ, "PYTHONPATH": str(src)}
    return subprocess.run(
        [sys.executable, "-m", "beambench", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )
