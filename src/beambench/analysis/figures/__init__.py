"""The report's figures, one module per figure, each registering itself in :data:`FIGURES` with the rigs it
applies to (``@FIGURES.add("key", rigs=(...), caption=...)``); the report draws ``FIGURES.for_rigs({rig})`` in the
order below. Adding a figure: a new module here and its line in this import list (docs/extending.md)."""

# isort: off  (the import order is the report's order)
from beambench.analysis.figures import (  # noqa: F401, I001  (each module registers its figure on import; report order)
    body_trajectory,
    contact_direction,
    contact_frequency,
    drift,
    ellipse,
    forces,
    frequency,
    gait,
    release_decay,
    sync,
    speed_tracking,
    trajectories,
    walking_speed,
)

# isort: on
from beambench.analysis.figures.registry import FIGURES, RIGS, FigureRegistry, FigureSpec, ReportOptions

__all__ = ["FIGURES", "RIGS", "FigureRegistry", "FigureSpec", "ReportOptions"]
