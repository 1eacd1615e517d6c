"""Model names (``sim.model``, a sweep's ``model``, ``beambench fit --model``) to their family, parameter file
and builder, through the family catalogue (:mod:`beambench.sim.models.families`).

Model names: ``prb3`` (the paper's pseudo-rigid body, :class:`~beambench.sim.models.beam.PRB3`) and the
segmented rods ``rod<N>[g][s]`` (:mod:`beambench.sim.models.rod`). A name's *family* is the prefix of its
parameter files, ``sim_backend/<family>_<set>.yaml``. To add a model, see ``docs/extending.md``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from beambench.common.errors import BeambenchError
from beambench.sim.models.families import BUILDERS, FAMILIES, ModelFamily
from beambench.sim.models.params import BeamParams, load_params

if TYPE_CHECKING:
    from beambench.sim.models.beam import BeamModel

__all__ = [
    "UnknownModelError",
    "beam_model",
    "canonical_model",
    "default_params",
    "family_of",
    "is_rod",
    "make_beam_model",
    "model_family",
]


class UnknownModelError(BeambenchError, ValueError):
    """A model name no family claims (one-line message; a ``ValueError`` so pydantic validators report it)."""


def family_of(name: str) -> ModelFamily:
    """The family that claims model ``name`` (:mod:`beambench.sim.models.families`); UnknownModelError otherwise."""
    for family in FAMILIES.values():
        m = family.names.fullmatch(name)
        if m:
            reason = family.refuse(m) if family.refuse is not None else None
            if reason:
                raise UnknownModelError(f"sim.model = {name[:40]!r}: unknown beam model ({reason})")
            return family
    known = ", ".join(f.grammar for f in FAMILIES.values())
    raise UnknownModelError(f"sim.model = {name[:40]!r}: unknown beam model (known: {known})")


def model_family(name: str) -> str:
    """The parameter-file prefix of a model name: ``rod10``, ``rod3g`` → ``rod``; ``prb3`` → ``prb3``."""
    return family_of(name).name


def canonical_model(name: str) -> str:
    """A model name with a family's own name resolved to its default model (``rod`` → ``rod10``); unknown names
    raise."""
    name = FAMILIES[name].default if name in FAMILIES else name
    family_of(name)
    return name


def is_rod(name: str) -> bool:
    """True for the segmented rods (their stiffness is a material, E and β; PRB3's is joint springs, k and b)."""
    return family_of(canonical_model(name)).segmented


def make_beam_model(name: str, params: BeamParams) -> BeamModel:
    """The model called ``name``, built by its family's registered builder (MuJoCo loads here, not with the name
    checks above)."""
    from beambench.sim.models import beam, rod  # noqa: F401  (the builder modules: each registers its family's)

    model = BUILDERS[model_family(name)](name, params)
    assert isinstance(model, beam.BeamModel), f"the {model_family(name)} builder made no BeamModel"
    return model


def default_params(name: str, params: str = "paper") -> BeamParams:
    """The named parameter set (``sim_backend/<family>_<params>.yaml``) of model ``name``'s family."""
    return load_params(params, model=model_family(canonical_model(name)))


def beam_model(name: str = "prb3", params: str | BeamParams = "paper") -> BeamModel:
    """A beam model by name with a named parameter set (or the parameters themselves)."""
    return make_beam_model(name, default_params(name, params) if isinstance(params, str) else params)
