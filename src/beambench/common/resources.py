"""Where beambench finds the data it ships (parameter sets, measured tables, calibration, protocols).

The one place that knows the layout: every module asks here instead of walking up from its own file.
"""

from __future__ import annotations

from pathlib import Path

_REPO_ROOT = Path(__file__).resolve().parents[3]


def shipped_dir(name: str) -> Path:
    """The shipped folder ``name``: ``sim_backend``, ``calibration`` or ``protocols``."""
    return _REPO_ROOT / name
