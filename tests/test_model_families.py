"""A beam model family is one catalogue entry plus a registered builder: a family declared here is a model name
wherever names are checked (family, default model, parameter-file prefix, the refusal's grammar) and
``make_beam_model`` builds it through its builder; a builder for an undeclared family is refused."""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import replace

import pytest

from beambench.sim.models import families
from beambench.sim.models.beam import PRB3
from beambench.sim.models.families import ModelFamily, beam_builder
from beambench.sim.models.params import BeamParams, load_params
from beambench.sim.models.registry import (
    UnknownModelError,
    canonical_model,
    is_rod,
    make_beam_model,
    model_family,
)


class Stiff(PRB3):
    """A PRB3 whose joint springs are ``n`` times stiffer (the family's models are ``stiff<n>``)."""


STIFF = ModelFamily("stiff", re.compile(r"stiff([1-9])"), "stiff<1-9>", default="stiff1")


@pytest.fixture
def stiff() -> Iterator[ModelFamily]:
    """The family declared, and its builder registered, for one test (the catalogue is process-wide)."""
    with families.FAMILIES.restoring(STIFF.name), families.BUILDERS.restoring(STIFF.name):
        families.declare(STIFF)

        @beam_builder(STIFF)
        def build(name: str, params: BeamParams) -> Stiff:
            return Stiff(replace(params, k=params.k * int(name.removeprefix("stiff"))))

        yield STIFF
    assert "stiff" not in families.FAMILIES and "stiff" not in families.BUILDERS


def test_a_declared_family_is_a_model_name_and_builds_through_its_builder(stiff):
    assert model_family("stiff3") == "stiff" and canonical_model("stiff") == "stiff1" and not is_rod("stiff2")
    params = load_params("paper", model="prb3")
    model = make_beam_model("stiff3", params)
    assert isinstance(model, Stiff) and model.params.k == pytest.approx(3 * params.k)
    with pytest.raises(UnknownModelError, match=r"known: prb3, rod<N>.*, stiff<1-9>"):
        model_family("stiff0")
    assert model_family("rod12") == "rod" and is_rod("rod") and canonical_model("rod") == "rod10"


def test_a_builder_needs_its_family_declared_once():
    undeclared = ModelFamily("loose", re.compile("loose"), "loose", default="loose")
    with pytest.raises(ValueError, match="not declared"):
        beam_builder(undeclared)(lambda name, params: None)
    with pytest.raises(ValueError, match="registered twice"):
        beam_builder(families.ROD)(lambda name, params: None)
    with pytest.raises(ValueError, match="declared twice"):
        families.declare(ModelFamily("rod", re.compile("rod"), "rod", default="rod"))


def test_the_walker_takes_its_legs_from_any_family_that_says_it_builds_them(stiff):
    """A newly declared family is a walker leg unless it says otherwise (``walker_leg``), and the refusal lists
    the families that are; what a model is never comes from a hand list of names."""
    from beambench.sim.scenes.walker import WalkerLegError, check_leg_model

    check_leg_model("stiff2")  # declared a moment ago: the walker builds it
    flat = ModelFamily("flat", re.compile("flat"), "flat", default="flat", walker_leg=False)
    with families.FAMILIES.restoring(flat.name):
        families.declare(flat)
        with pytest.raises(
            WalkerLegError, match=r"^sim.model = 'flat': refused for the walker: .* prb3 or rod or stiff$"
        ):
            check_leg_model("flat")
