"""Torsion of the pre-twisted strip: the extension–twist ("trapeze") term against its derivation and against the
free torsional vibration of a fine rod."""

from __future__ import annotations

import math
from dataclasses import replace

import mujoco
import numpy as np
import pytest

from beambench.sim.models.rod import RodParams, add_rod, natural_frequencies

STRIP = RodParams(n_segments=40, youngs_modulus=26e6)  # 50 x 20 x 3 mm


def _energy_stiffness(rod: RodParams, twist_deg: float) -> float:
    """The trapeze stiffness from the strain energy of the fibres, integrated numerically across the width.

    A fibre at distance y from the axis of a strip twisted at rate κ runs along a helix; an added twist rate θ'
    stretches it by κ·θ'·y², less the mean over the width (the strip is free to shorten). Energy per length
    ½·E·t·∫ε² dy = ½·K·θ'², so K = E·t·κ²·∫(y² − ⟨y²⟩)² dy."""
    kappa = math.radians(twist_deg) / rod.length
    y = np.linspace(-rod.width / 2, rod.width / 2, 20001)
    strain = y**2 - np.trapezoid(y**2, y) / rod.width
    return rod.youngs_modulus * rod.thickness * kappa**2 * float(np.trapezoid(strain**2, y))


@pytest.mark.parametrize("twist_deg", [30.0, 90.0, -90.0, 180.0])
def test_trapeze_term_is_the_fibre_strain_energy(twist_deg):
    """E·κ²·t·w⁵/180 equals the fibres' strain-energy stiffness within 0.1 %, either chirality."""
    assert STRIP.trapeze_gj(twist_deg) == pytest.approx(_energy_stiffness(STRIP, twist_deg), rel=1e-3)


def test_a_quarter_turn_over_50_mm_nearly_doubles_the_torsion_stiffness():
    """The paper's strip (90° over 50 mm): GJ_twisted/GJ ≈ 1.9, growing as φ²; a straight strip has none;
    switching the term off leaves Saint-Venant's GJ."""
    ratio = STRIP.torsion_gj(90.0) / STRIP.gj
    assert 1.85 < ratio < 1.97, ratio
    assert STRIP.trapeze_gj(180.0) == pytest.approx(4 * STRIP.trapeze_gj(90.0))
    assert STRIP.torsion_gj(0.0) == STRIP.gj
    assert replace(STRIP, trapeze=False).torsion_gj(90.0) == STRIP.gj


def _torsion_mode(rod: RodParams, twist_deg: float) -> float:
    """The lowest natural frequency whose mode shape lives in the twist hinges (clamped rod, no gravity)."""
    spec = mujoco.MjSpec()
    spec.option.gravity = [0, 0, 0]
    add_rod(spec.worldbody, rod, twist_deg)
    m = spec.compile()
    f, vecs = natural_frequencies(m, modes=True)
    dofs = np.array([m.jnt_dofadr[j] for j in range(m.njnt) if m.joint(j).name.endswith("twist")])
    for k in range(len(f)):
        v = vecs[:, k]
        if np.sum(v[dofs] ** 2) > 0.9 * np.sum(v**2):
            return float(f[k])
    raise AssertionError("no torsion mode")


def test_the_twisted_rods_torsion_mode_is_the_continuum_value_with_the_trapeze_term():
    """Free torsional vibration of the clamped 90°-twisted rod (40 segments): its first torsion mode is the
    continuum's f = √(GJ_twisted / ρI_p) / 4L within 2 % (ρI_p = ρA(w² + t²)/12), ~1.4x the frequency of the
    same rod without the term, which in turn matches Saint-Venant's GJ: the term reaches the dynamics."""
    rho_ip = STRIP.density * STRIP.area * (STRIP.width**2 + STRIP.thickness**2) / 12

    def continuum(gj: float) -> float:
        return math.sqrt(gj / rho_ip) / (4 * STRIP.length)

    twisted = _torsion_mode(STRIP, 90.0)
    assert twisted == pytest.approx(continuum(STRIP.torsion_gj(90.0)), rel=0.02)
    plain = _torsion_mode(replace(STRIP, trapeze=False), 90.0)
    assert plain == pytest.approx(continuum(STRIP.gj), rel=0.02)
    assert twisted / plain == pytest.approx(math.sqrt(STRIP.torsion_gj(90.0) / STRIP.gj), rel=0.01)
