"""Figures without pyplot: library code never switches the user's matplotlib backend (a notebook keeps its own)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def new_figure(**kwargs: Any) -> Figure:
    """A :class:`matplotlib.figure.Figure` (``figsize``, ``dpi``, ``layout`` …) on its own Agg canvas, so it can
    measure text and ``savefig`` without pyplot; it is freed with the last reference (no ``plt.close``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(**kwargs)
    FigureCanvasAgg(fig)
    return fig
