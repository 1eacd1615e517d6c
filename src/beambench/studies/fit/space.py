"""What a release fit searches and what it fits: the measured markers around a release (:class:`ReleaseData`) and a
model family's searched variables mapped onto a parameter set (:class:`ParamSpace`). Shared by the fit
(:mod:`.release`) and its least-squares step (:mod:`.sysid`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from beambench.sim.models.params import BeamParams
from beambench.sim.models.registry import default_params, family_of, model_family
from beambench.studies.unknowns import BEAM_OVERRIDES, Unknown

__all__ = ["ParamSpace", "ReleaseData"]


@dataclass
class ReleaseData:
    """Measured tip markers around a release: ``markers`` [n, M, 3] (m, clamp frame, NaN where occluded) at
    ``t`` [n] (s from the release); the scene facts the simulation needs; ``truth`` the generating model's
    parameters when the data came from the sim."""

    t: np.ndarray
    markers: np.ndarray
    names: tuple[str, ...]
    twist_deg: float = 90.0
    load_g: float = 200.0
    length: float = 0.050
    source: str = ""
    release_uncertainty_s: float = 0.0  # how far the release instant may be off: the fit searches ± this
    clamp_relative: bool = True  # positions are relative to the clamp (a stage marker was recorded)
    truth: dict[str, Any] = field(default_factory=dict)

    def window(self, pre_s: float, post_s: float) -> ReleaseData:
        sel = (self.t >= -pre_s) & (self.t <= post_s)
        return replace(self, t=self.t[sel], markers=self.markers[sel])


@dataclass(frozen=True)
class ParamSpace:
    """The searched variables of one model family (:class:`~beambench.studies.unknowns.Unknown` s, as a
    calibration's) and how they map onto a :class:`BeamParams` (the beam's own overrides,
    :data:`~beambench.studies.unknowns.BEAM_OVERRIDES`; ``l2_share`` is resolved into l2 first)."""

    model: str  # prb3 | rodN…
    variables: tuple[Unknown, ...]
    base: BeamParams
    free_l1: bool = False

    @staticmethod
    def prb3(base: BeamParams, free_l1: bool = False) -> ParamSpace:
        L = base.length
        v = [Unknown("k", 0.1, 2.0, True, "N·m/rad"), Unknown("b", 2e-4, 0.03, True, "N·m·s/rad")]
        if free_l1:
            v += [Unknown("l1", 0.001, 0.4 * L, False, "m"), Unknown("l2_share", 0.1, 0.9, False, "")]
        else:
            v += [Unknown("l2", 0.1 * L, 0.9 * L, False, "m")]
        return ParamSpace("prb3", tuple(v), base, free_l1)

    @staticmethod
    def rod(base: BeamParams, model: str = "rod10") -> ParamSpace:
        """E and β within their physical ranges: the set's own ``bounds:`` where it has them, else those of the
        shipped physical set (``sim_backend/rod_physical.yaml``: printed TPU 95A 12–30 MPa, β 0.4–10 ms)."""
        keys = {"youngs_modulus": "beam.material.youngs_modulus", "beta": "beam.beta"}
        physical = (
            base.bounds if all(k in base.bounds for k in keys.values()) else default_params(model, "physical").bounds
        )
        b = {name: physical[key] for name, key in keys.items()}
        v = (
            Unknown("youngs_modulus", b["youngs_modulus"].min, b["youngs_modulus"].max, True, "Pa"),
            Unknown("beta", b["beta"].min, b["beta"].max, True, "s"),
        )
        return ParamSpace(model, v, base)

    def bounds(self) -> list[tuple[float, float]]:
        return [v.bounds for v in self.variables]

    def values(self, x: Sequence[float] | np.ndarray) -> dict[str, float]:
        """Physical values of a search vector (``l2_share`` resolved into l2)."""
        out = {v.name: v.value(xi) for v, xi in zip(self.variables, x)}
        if not family_of(self.model).segmented:  # joint springs between three links (PRB3)
            L = self.base.length
            if self.free_l1:
                out["l2"] = out.pop("l2_share") * (L - out["l1"])
            else:
                out["l1"] = 0.0
            out["l3"] = L - out["l1"] - out["l2"]
            out = {k: out[k] for k in ("k", "b", "l1", "l2", "l3")}
        return out

    def params(self, x: Sequence[float] | np.ndarray, name: str = "fit") -> BeamParams:
        p = replace(self.base, name=name, model=model_family(self.model))
        for key, value in self.values(x).items():
            p = BEAM_OVERRIDES[key](p, value)
        return p
