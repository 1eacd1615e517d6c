"""The report's figures as a registry: each figure module registers itself with ``@FIGURES.add``, naming the
rigs it applies to, and the report draws the figures of the session's rig (as dm_control's ``@SUITE.add``)."""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from beambench.common.figures import STYLE

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import SessionAnalysis

RIGS = ("contact", "walker", "release")  # the rig names a session records in /general


@dataclass(frozen=True)
class ReportOptions:
    """Choices of the report that some figures take (e.g. the force-trace frequencies)."""

    force_at: list[float] | None = None


Draw = Callable[["list[SessionAnalysis]", Path, ReportOptions], "Path | None"]


@dataclass(frozen=True)
class FigureSpec:
    """One report figure: its file stem, the rigs it is drawn for, its caption and how it is drawn (``draw``
    returns None when the sessions hold nothing to show)."""

    key: str
    rigs: frozenset[str]
    caption: str | Mapping[str, str]  # one text, or one per rig
    draw: Draw

    def caption_for(self, rig: str) -> str:
        if isinstance(self.caption, str):
            return self.caption
        return self.caption.get(rig) or next(iter(self.caption.values()), "")

    def applies_to(self, rigs: set[str]) -> bool:
        """Drawn for a report whose sessions are all of rigs this figure applies to."""
        return bool(rigs) and rigs <= self.rigs


class FigureRegistry:
    """Figures in registration order (the order of the report)."""

    def __init__(self) -> None:
        self._specs: dict[str, FigureSpec] = {}

    def add(self, key: str, rigs: tuple[str, ...], caption: str | Mapping[str, str]) -> Callable[[Draw], Draw]:
        """Register the decorated ``draw(analyses, path, options)`` as figure ``key`` for ``rigs``; it is drawn
        under the report's matplotlib style."""
        unknown = set(rigs) - set(RIGS)
        if unknown or not rigs:
            raise ValueError(f"figure {key!r}: unknown rigs {sorted(unknown)} (known: {', '.join(RIGS)})")
        if key in self._specs:
            raise ValueError(f"figure {key!r} is registered twice")

        def decorator(fn: Draw) -> Draw:
            self._specs[key] = FigureSpec(key, frozenset(rigs), caption, styled(fn))
            return fn

        return decorator

    def __iter__(self) -> Iterator[FigureSpec]:
        return iter(self._specs.values())

    def __getitem__(self, key: str) -> FigureSpec:
        return self._specs[key]

    def keys(self) -> list[str]:
        return list(self._specs)

    def for_rigs(self, rigs: set[str]) -> list[FigureSpec]:
        """The figures of a report on sessions of ``rigs`` (one rig for analyze; compare may mix)."""
        return [s for s in self if s.applies_to(rigs)]


FIGURES = FigureRegistry()


def styled(fn: Draw) -> Draw:
    """Draw under the report's style without touching the global rcParams or pyplot's backend."""

    @functools.wraps(fn)
    def wrapper(analyses: list[SessionAnalysis], path: Path, options: ReportOptions) -> Path | None:
        import matplotlib

        with matplotlib.rc_context(cast(Any, STYLE)):
            return fn(analyses, path, options)

    return wrapper
