"""The one registry every pluggable thing uses (scenes, beam builders, sim streams, rig builders, figures,
calibratable rigs): a name once, an unknown name answered with the known ones, registration order kept."""

from __future__ import annotations

import pytest

from beambench.common.registry import DuplicateName, Registry, UnknownName


def _shapes() -> Registry[int]:
    reg: Registry[int] = Registry("shape")
    reg.add("square", 4)
    reg.add("triangle", 3)

    @reg.register("hexagon")
    def _six() -> int:  # the decorator registers the object itself and hands it back
        return 6

    return reg


def test_a_name_is_registered_once_and_the_first_item_stays():
    reg = _shapes()
    with pytest.raises(DuplicateName, match=r"^shape 'square' is registered twice$"):
        reg.add("square", 5)
    with pytest.raises(ValueError, match="registered twice"):  # a ValueError, as the registries raised before
        reg.register("triangle")(33)
    assert reg["square"] == 4 and reg["triangle"] == 3


def test_an_unknown_name_is_a_key_error_listing_the_known_ones():
    reg = _shapes()
    with pytest.raises(UnknownName) as err:
        reg["circle"]
    assert isinstance(err.value, KeyError)
    assert str(err.value) == "shape 'circle' is not registered (registered: square, triangle, hexagon)"
    declared: Registry[str] = Registry("family", verb="declared", missing="has no builder")
    with pytest.raises(KeyError, match=r"^family 'rod' has no builder \(no family is declared\)$"):
        declared["rod"]
    assert declared.get("rod") is None and "rod" not in declared


def test_iteration_keeps_registration_order():
    reg = _shapes()
    assert list(reg) == ["square", "triangle", "hexagon"]
    assert [k for k, _ in reg.items()][::-1] == ["hexagon", "triangle", "square"] and len(reg) == 3
    assert reg["hexagon"]() == 6


def test_a_stand_in_or_a_registration_in_a_restoring_block_is_undone_for_that_name_only():
    reg = _shapes()
    with reg.stand_in("triangle", 30) as item:
        assert item == 30 and reg["triangle"] == 30 and list(reg) == ["square", "triangle", "hexagon"]
    with reg.stand_in("circle", 0):
        assert list(reg) == ["square", "triangle", "hexagon", "circle"]
    with reg.restoring("pentagon"):
        reg.add("pentagon", 5)
        reg.add("heptagon", 7)  # registered meanwhile by something else (a module imported on the way): kept
        assert reg["pentagon"] == 5
    assert dict(reg.items()) == {"square": 4, "triangle": 3, "hexagon": reg["hexagon"], "heptagon": 7}
