"""The report's figures as a registry: each figure module registers itself with ``@FIGURES.add``, saying which
scenes it applies to by their flags (a predicate on :class:`~beambench.acquisition.protocol.scenes.SceneInfo`), and
the report draws the figures of the session's rig (as dm_control's ``@SUITE.add``). The rigs come from the scene
catalogue, so a newly declared scene gets every figure its flags call for."""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from beambench.acquisition.protocol.scenes import SceneInfo, runnable_scenes, scene_or_unknown
from beambench.common.figures import STYLE
from beambench.common.registry import Registry

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import SessionAnalysis

ScenePredicate = Callable[[SceneInfo], bool]
Caption = str | Callable[[SceneInfo], str]  # one text, or one made from the session's scene


def any_scene(scene: SceneInfo) -> bool:
    """Every rig (a figure such as the clock fits applies to any session)."""
    return True


@dataclass(frozen=True)
class ReportOptions:
    """Choices of the report that some figures take (e.g. the force-trace frequencies)."""

    force_at: list[float] | None = None


Draw = Callable[["list[SessionAnalysis]", Path, ReportOptions], "Path | None"]


@dataclass(frozen=True)
class FigureSpec:
    """One report figure: its file stem, the scenes it is drawn for (a predicate on their flags), its caption and
    how it is drawn (``draw`` returns None when the sessions hold nothing to show)."""

    key: str
    scenes: ScenePredicate
    caption: Caption
    draw: Draw

    @property
    def rigs(self) -> frozenset[str]:
        """The rigs of the scene catalogue this figure is drawn for."""
        return frozenset(s.name for s in runnable_scenes() if self.scenes(s))

    def caption_for(self, rig: str) -> str:
        return self.caption if isinstance(self.caption, str) else self.caption(scene_or_unknown(rig))

    def applies_to(self, rigs: set[str]) -> bool:
        """Drawn for a report whose sessions are all of rigs this figure applies to."""
        return bool(rigs) and rigs <= self.rigs


class FigureRegistry:
    """Figures in registration order (the order of the report)."""

    def __init__(self) -> None:
        self._specs: Registry[FigureSpec] = Registry("figure")

    def add(self, key: str, scenes: ScenePredicate, caption: Caption) -> Callable[[Draw], Draw]:
        """Register the decorated ``draw(analyses, path, options)`` as figure ``key`` for the rigs whose
        :class:`SceneInfo` ``scenes`` accepts (e.g. ``lambda s: s.plate``); it is drawn under the report's
        matplotlib style. A predicate no rig of the catalogue meets, or a second figure ``key``, fails here."""
        self._specs.check_free(key)
        if not any(scenes(s) for s in runnable_scenes()):
            known = ", ".join(s.name for s in runnable_scenes())
            raise ValueError(f"figure {key!r}: applies to no rig of the scene catalogue ({known})")

        def decorator(fn: Draw) -> Draw:
            self._specs.add(key, FigureSpec(key, scenes, caption, styled(fn)))
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
