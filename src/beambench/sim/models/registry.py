"""The one place that maps a model name (``sim.model``, a sweep's ``model``, ``beambench fit --model``) to its
family, parameter file and builder.

Model names: ``prb3`` (the paper's pseudo-rigid body, :class:`~beambench.sim.models.beam.PRB3`) and the
segmented rods ``rod<N>[g][s]`` (:mod:`beambench.sim.models.rod`). A name's *family* is the prefix of its
parameter files, ``sim_backend/<family>_<set>.yaml``. To add a model, see ``docs/extending.md``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal, get_args

from beambench.common.errors import BeambenchError
from beambench.sim.models.names import ROD_NAME
from beambench.sim.models.params import BeamParams, load_params

if TYPE_CHECKING:
    from beambench.sim.models.beam import BeamModel

Family = Literal["prb3", "rod"]
FAMILIES: tuple[Family, ...] = get_args(Family)
DEFAULT_ROD = "rod10"  # what the family name ``rod`` means where a model name is expected (``fit --model rod``)
MAX_SEGMENTS = 200  # a rod with more joints takes minutes per simulated second and GBs to build


class UnknownModelError(BeambenchError, ValueError):
    """A model name no family claims (one-line message; a ``ValueError`` so pydantic validators report it)."""


def model_family(name: str) -> Family:
    """The parameter-file prefix of a model name: ``rod10``, ``rod3g`` → ``rod``; ``prb3`` → ``prb3``."""
    if name == "prb3":
        return "prb3"
    m = ROD_NAME.fullmatch(name)
    if m:
        if not 1 <= int(m.group(1)) <= MAX_SEGMENTS:
            raise UnknownModelError(
                f"sim.model = {name[:40]!r}: unknown beam model (a rod has 1 to {MAX_SEGMENTS} segments)"
            )
        return "rod"
    raise UnknownModelError(
        f"sim.model = {name[:40]!r}: unknown beam model (known: prb3, rod<N>[g][s] with N <= {MAX_SEGMENTS}, e.g. rod10)"
    )


def canonical_model(name: str) -> str:
    """A model name with the family shorthand resolved (``rod`` → ``rod10``); unknown names raise."""
    name = DEFAULT_ROD if name == "rod" else name
    model_family(name)
    return name


def is_rod(name: str) -> bool:
    """True for the segmented rods (their stiffness is a material, E and β; PRB3's is joint springs, k and b)."""
    return model_family(canonical_model(name)) == "rod"


def make_beam_model(name: str, params: BeamParams) -> BeamModel:
    """The model called ``name``: ``prb3``, or a segmented rod ``rod<N>[g][s]`` (:mod:`beambench.sim.models.rod`)."""
    from beambench.sim.models.beam import PRB3  # MuJoCo loads here, not with the name checks above
    from beambench.sim.models.rod import make_rod_model

    if model_family(name) == "rod":
        return make_rod_model(name, params)
    return PRB3(params)


def default_params(name: str, params: str = "paper") -> BeamParams:
    """The named parameter set (``sim_backend/<family>_<params>.yaml``) of model ``name``'s family."""
    return load_params(params, model=model_family(canonical_model(name)))


def beam_model(name: str = "prb3", params: str | BeamParams = "paper") -> BeamModel:
    """A beam model by name with a named parameter set (or the parameters themselves)."""
    return make_beam_model(name, default_params(name, params) if isinstance(params, str) else params)
