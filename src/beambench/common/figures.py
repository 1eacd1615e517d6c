"""Figures without pyplot (library code never switches the user's matplotlib backend: a notebook keeps its own),
and the style every beambench figure shares: the report's rcParams and one legend below the panels."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any, cast

import numpy as np

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


STYLE: dict[str, Any] = {
    "axes.grid": True,
    "grid.alpha": 0.3,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "font.size": 10,
    "axes.titlesize": 10,
    "legend.fontsize": 9,
    "legend.frameon": False,
}


@contextlib.contextmanager
def shared_style() -> Iterator[None]:
    """Draw under :data:`STYLE` without touching the global rcParams."""
    import matplotlib

    with matplotlib.rc_context(cast(Any, STYLE)):
        yield


def legend_below(fig: Figure, axes: Any, ncol: int = 4, handles: list[Any] | None = None, **kw: Any) -> None:
    """One legend for the figure, below every panel (a legend inside hides traces), duplicate labels merged.
    ``loc="outside …"`` makes the constrained layout keep it inside the canvas."""
    if handles is None:
        seen: dict[str, Any] = {}
        for ax in np.ravel(axes):
            for h, label in zip(*ax.get_legend_handles_labels()):
                seen.setdefault(label, h)
        handles_, labels = list(seen.values()), list(seen)
    else:
        handles_, labels = handles, [h.get_label() for h in handles]
    if handles_:
        ncol = fitting_columns(labels, float(fig.get_figwidth()), ncol)
        fig.legend(handles_, labels, loc="outside lower center", ncol=ncol, **kw)


def fitting_columns(labels: list[str], width_in: float, ncol: int) -> int:
    """At most ``ncol`` legend columns, as many as fit the figure's width (a legend wider than the figure is cut
    at both edges): every column as wide as the longest label at the legend's font size, plus its handle."""
    import matplotlib
    from matplotlib.font_manager import FontProperties

    size = FontProperties(size=matplotlib.rcParams["legend.fontsize"]).get_size_in_points()
    column_in = max((len(s) for s in labels), default=1) * 0.56 * size / 72 + 0.75
    return max(1, min(ncol, len(labels), int(width_in / column_in)))
