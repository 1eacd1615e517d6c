"""The one place that maps a model name (``sim.model``) to its family, parameter file and builder."""

from __future__ import annotations

import re

from beambench.sim.models.beam import PRB3, BeamModel
from beambench.sim.models.params import BeamParams, load_params
from beambench.sim.models.rod import ROD_NAME, make_rod_model

FAMILIES = ("prb3", "rod")
MAX_SEGMENTS = 200  # a rod with more joints takes minutes per simulated second and GBs to build


def model_family(name: str) -> str:
    """The parameter-file prefix of a model name: ``rod10``, ``rod3g`` → ``rod``; ``prb3`` → ``prb3``."""
    if name == "prb3":
        return "prb3"
    m = re.fullmatch(ROD_NAME, name)
    if m:
        if not 1 <= int(m.group(1)) <= MAX_SEGMENTS:
            raise ValueError(f"sim.model = {name[:40]!r}: a rod has 1 to {MAX_SEGMENTS} segments")
        return "rod"
    raise ValueError(f"sim.model = {name[:40]!r}: unknown beam model (known: prb3, rod<N>[g][s], N <= {MAX_SEGMENTS})")


def make_beam_model(name: str, params: BeamParams) -> BeamModel:
    """The model called ``name``: ``prb3``, or a segmented rod ``rod<N>[g][s]`` (:mod:`beambench.sim.models.rod`)."""
    if model_family(name) == "rod":
        return make_rod_model(name, params)
    return PRB3(params)


def beam_model(name: str = "prb3", params: str | BeamParams = "paper") -> BeamModel:
    """A beam model by name with a named parameter set (or the parameters themselves)."""
    family = model_family(name)
    return make_beam_model(name, load_params(params, model=family) if isinstance(params, str) else params)
