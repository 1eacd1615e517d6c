"""The beam model families, as the name checks need them (no MuJoCo), and the registry of their builders.

A family is a parameter-file prefix (``sim_backend/<family>_<set>.yaml``) and the model names it claims
(:class:`ModelFamily`); :func:`declare` adds one here. The module that builds the family's models (it imports
MuJoCo) registers its builder against the same entry with ``@beam_builder(FAMILY)``, and
:func:`beambench.sim.models.registry.make_beam_model` imports those modules by name, as the scenes do
(docs/extending.md, "A beam model").
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypeVar

from beambench.common.registry import Registry
from beambench.sim.models.names import ROD_NAME

if TYPE_CHECKING:
    from beambench.sim.models.params import BeamParams

MAX_SEGMENTS = 200  # a rod with more joints takes minutes per simulated second and GBs to build


@dataclass(frozen=True)
class ModelFamily:
    """One family of beam models."""

    name: str
    """The prefix of its parameter files, and the name its default model goes by (``rod`` → ``rod10``)."""
    names: re.Pattern[str]
    """The model names it claims (a full match)."""
    grammar: str
    """Its names in words, for the refusal of a name no family claims."""
    default: str
    """The model the family's own name means where a model name is expected (``fit --model rod``)."""
    segmented: bool = False
    """Its stiffness is a material (E, β) over segments, not joint springs (k, b) between rigid links (l1, l2, l3)
    fitted without the physical set's E."""
    walker_leg: bool = True
    """The walker builds its legs from this family's models."""
    refuse: Callable[[re.Match[str]], str | None] | None = None
    """Why a claimed name is still refused (e.g. too many segments), else None."""


FAMILIES: Registry[ModelFamily] = Registry("beam model family", verb="declared")
"""Every declared family by name, in declaration order."""
Builder = Callable[[str, "BeamParams"], object]
BUILDERS: Registry[Builder] = Registry("builder of beam model family")
"""Each family's model builder ``(model name, parameters) → BeamModel`` (the builder modules import this one,
so it names no model type), registered by its module."""
B = TypeVar("B", bound=Builder)


def declare(family: ModelFamily) -> ModelFamily:
    """Add a family (a name is declared once)."""
    return FAMILIES.add(family.name, family)


def beam_builder(family: ModelFamily) -> Callable[[B], B]:
    """Register the decorated ``build(name, params)`` as the builder of ``family``'s models."""

    def add(build: B) -> B:
        if family.name not in FAMILIES:
            raise ValueError(FAMILIES.unknown(family.name))
        if FAMILIES[family.name] is not family:
            raise ValueError(f"beam model family {family.name!r}: another family of that name is declared")
        BUILDERS.add(family.name, build)
        return build

    return add


def _too_many_segments(m: re.Match[str]) -> str | None:
    return None if 1 <= int(m.group(1)) <= MAX_SEGMENTS else f"a rod has 1 to {MAX_SEGMENTS} segments"


PRB3 = declare(ModelFamily("prb3", re.compile("prb3"), "prb3", default="prb3"))
"""The paper's pseudo-rigid body: three links on joint springs (:class:`beambench.sim.models.beam.PRB3`)."""
PAPER_MODEL = PRB3.default
"""The model the paper simulates (and a protocol's ``sim.model`` unless it names another): the reference of cost in
the model ladder's charts."""
ROD = declare(
    ModelFamily(
        "rod",
        ROD_NAME,
        f"rod<N>[g][s] with N <= {MAX_SEGMENTS}, e.g. rod10",
        default="rod10",
        segmented=True,
        refuse=_too_many_segments,
    )
)
"""The segmented rods ``rod<N>[g][s]`` (:mod:`beambench.sim.models.rod`)."""
