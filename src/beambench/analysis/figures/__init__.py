"""The report's figures, one module per figure, each registering itself in :data:`FIGURES` with the scenes it
applies to, by their catalogue flags (``@FIGURES.add("key", scenes=lambda s: s.plate, caption=...)``); the report
draws ``FIGURES.for_rigs({rig})`` in the order below. Adding a figure: a new module here and its line in this import list (docs/extending.md)."""

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
from beambench.analysis.figures.registry import FIGURES, FigureRegistry, FigureSpec, ReportOptions, any_scene

__all__ = ["FIGURES", "FigureRegistry", "FigureSpec", "ReportOptions", "any_scene"]
