"""The contact scene's optional parts: a compliant sole, the load frame's own mass and the
load's offset along the beam axis — each does what its physical meaning says."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from beambench.sim.models.params import load_params
from beambench.sim.models.registry import make_beam_model
from beambench.sim.scene_params import RigParams
from beambench.sim.scenes.contact_regimes import static_sag
from beambench.sim.scenes.contact_rig import build_contact_spec
from beambench.sim.scenes.free_beam import equilibrium_qpos


def _beam():
    return make_beam_model("prb3", load_params("contact_paper"))


def _at_rest(rig: RigParams, gap: float) -> tuple[mujoco.MjModel, mujoco.MjData]:
    m = build_contact_spec(_beam(), 90.0, gap, rig).compile()
    d = mujoco.MjData(m)
    d.qpos[:] = equilibrium_qpos(m, 1.5, mujoco.mjtIntegrator.mjINT_IMPLICITFAST, 1e-4)
    mujoco.mj_forward(m, d)
    return m, d


def _normal(m: mujoco.MjModel, d: mujoco.MjData) -> float:
    adr = m.sensor("plate_force").adr[0]
    return float(-d.sensordata[adr + 3])  # contact sensor: force of the foot on the plate, global z


@pytest.mark.parametrize("stiffness", [500.0, 2000.0])
def test_compliant_sole_compresses_by_the_plate_force_over_its_stiffness(stiffness):
    """Foot resting on the plate (0.4 mm interference): the sole's spring carries the plate force less the
    pad's own weight, K·q = N − m_s·g, and it is compressed (pushed up towards the frame)."""
    rig = RigParams.with_overrides(
        {"sole_stiffness": stiffness, "sole_damping": 2.0, "sole_mass": 3e-4, "friction": 1.5}
    )
    gap = static_sag(_beam(), rig) - 4e-4
    m, d = _at_rest(rig, gap)
    q = float(d.qpos[m.jnt_qposadr[m.joint("sole_slide").id]])
    n = _normal(m, d)
    assert n > 0.02  # a real preload, in newtons
    assert q > 0  # compressed
    assert stiffness * q == pytest.approx(n - 3e-4 * 9.81, rel=0.05)


def test_sole_travel_stops_the_compression():
    """With 20 µm of travel the frame bottoms out on the sole: the compression stays at the stop (the limit's
    soft-constraint overshoot aside) although K·q would need more."""
    rig = RigParams.with_overrides({"sole_stiffness": 200.0, "sole_damping": 2.0, "sole_travel": 2e-5})
    gap = static_sag(_beam(), rig) - 4e-4
    m, d = _at_rest(rig, gap)
    q = float(d.qpos[m.jnt_qposadr[m.joint("sole_slide").id]])
    n = _normal(m, d)
    assert n > 2 * 200.0 * 2e-5  # the spring alone carries only 4 mN at the stop
    assert q == pytest.approx(2e-5, abs=5e-6)


def test_frame_mass_hangs_on_the_tip_and_adds_to_the_sag():
    beam = _beam()
    plain, framed = RigParams(), RigParams.with_overrides({"frame_mass": 0.01})
    m0 = build_contact_spec(beam, 90.0, 0.2, plain).compile()
    m1 = build_contact_spec(beam, 90.0, 0.2, framed).compile()
    tip = "beam_tip"
    assert m1.body_subtreemass[m1.body(tip).id] - m0.body_subtreemass[m0.body(tip).id] == pytest.approx(0.01)
    # spread along the foot: its centre of mass is half-way down the frame, not at the sole
    assert static_sag(beam, framed) > static_sag(beam, plain) + 1e-3


def test_mass_dy_moves_the_load_along_the_beam_axis():
    """The load's offset along y shifts the tip body's centre of mass along y (and not along x)."""
    beam = _beam()
    dy = 0.01
    m0 = build_contact_spec(beam, 90.0, 0.2, RigParams()).compile()
    m1 = build_contact_spec(beam, 90.0, 0.2, RigParams.with_overrides({"mass_dy": dy})).compile()
    d0, d1 = mujoco.MjData(m0), mujoco.MjData(m1)
    mujoco.mj_forward(m0, d0)
    mujoco.mj_forward(m1, d1)
    tip0, tip1 = m0.body("beam_tip").id, m1.body("beam_tip").id
    shift = d1.subtree_com[tip1] - d0.subtree_com[tip0]
    share = 0.020 / m1.body_subtreemass[tip1]
    assert shift[1] == pytest.approx(dy * share, rel=0.05)
    assert abs(shift[0]) < 1e-4
    assert np.isfinite(static_sag(beam, RigParams.with_overrides({"mass_dy": dy})))


def _rod_beam():
    return make_beam_model("rod5g", load_params("physical", model="rod"))


def test_the_load_frame_meets_the_plate_at_its_corner():
    """``sole_at_corner``: the frame's lower corner (10 mm along the travel, 15 mm along the beam from the point
    below the tip) carries the 20 g and is what touches the plate. Unloaded (no gravity), the plate lies h' below
    that corner; at rest on the plate (0.3 mm preload) the contact is at the corner, > 10 mm from below the tip."""
    rig = RigParams.with_overrides(
        {"sole_at_corner": True, "mass_dx": 0.010, "mass_dy": 0.015, "clamp_roll_deg": 90.0, "friction": 1.0}
    )
    spec = build_contact_spec(_rod_beam(), 90.0, 0.0055, rig)
    spec.option.gravity = [0, 0, 0]
    m = spec.compile()
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    sole = d.geom_xpos[m.geom("sole").id]
    tip = d.site_xpos[m.site("beam_tip_site").id]
    assert sole[:2] - tip[:2] == pytest.approx([0.010, 0.015], abs=1e-9)
    plate_top = d.site_xpos[m.site("plate_site").id][2]
    assert (sole[2] - rig.sole_radius) - plate_top == pytest.approx(0.0055, abs=1e-9)
    assert d.site_xpos[m.site("foot").id] == pytest.approx(sole - [0, 0, rig.sole_radius], abs=1e-9)

    gap = static_sag(_rod_beam(), rig) - 3e-4
    m = build_contact_spec(_rod_beam(), 90.0, gap, rig).compile()
    d = mujoco.MjData(m)
    d.qpos[:] = equilibrium_qpos(m, 1.5, mujoco.mjtIntegrator.mjINT_IMPLICITFAST, 1e-4)
    mujoco.mj_forward(m, d)
    # the plate carries the preload's share: the corner's stiffness (~0.3 N over ~5 mm of sag) x 0.3 mm
    assert 0.005 < _normal(m, d) < 0.05
    tip = d.site_xpos[m.site("beam_tip_site").id]
    assert d.ncon >= 1 and np.linalg.norm(d.contact[0].pos[:2] - tip[:2]) > 0.010  # the tilted frame: ~13 mm


def test_a_corner_beyond_the_tip_sags_more_by_the_tips_rotation():
    """The corner is a lever on the tip's rotation: moved away from the stage along the beam it sinks more under
    the same 20 g, moved toward the stage less, and the differences are those of the lever (the sag grows with
    the offset, the moment too: a convex rise)."""
    sags = [
        static_sag(
            _rod_beam(),
            RigParams.with_overrides({"sole_at_corner": True, "mass_dy": dy, "clamp_roll_deg": 90.0}),
        )
        for dy in (-0.015, 0.0, 0.015, 0.030)
    ]
    assert sags[0] < sags[1] < sags[2] < sags[3], sags
    assert sags[3] - sags[2] > sags[2] - sags[1] > 0, sags


def test_the_corner_switch_is_true_or_false_in_a_parameter_set():
    """``rig.sole_at_corner`` is a switch: a number there is refused with one line naming the field."""
    from beambench.sim.models.params import ParamsError, params_from_dict

    assert params_from_dict({"beam": {}, "rig": {"sole_at_corner": True}}).rig == {"sole_at_corner": True}
    with pytest.raises(ParamsError, match=r"rig\.sole_at_corner = 3: must be true or false"):
        params_from_dict({"beam": {}, "rig": {"sole_at_corner": 3}})
