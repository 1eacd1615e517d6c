"""The beam models: the paper's parameter set, PRB3 structure, chirality mirror, energy decay."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from beambench.backends.sim_devices import interp_rows
from beambench.common.errors import BeambenchError
from beambench.sim.models.beam import add_beam
from beambench.sim.models.params import ParamsError, available, load_params
from beambench.sim.models.registry import (
    UnknownModelError,
    beam_model,
    canonical_model,
    is_rod,
    make_beam_model,
    model_family,
)
from beambench.sim.scenes.contact_rig import ContactRigSim


@pytest.fixture(scope="module")
def paper():
    return load_params("paper")


def test_paper_parameter_set(paper):
    assert "paper" in available("prb3")
    assert (paper.l1, paper.l2, paper.l3) == (0.0, 0.02366, 0.02634)
    assert paper.length == pytest.approx(0.050)
    assert (paper.k, paper.b, paper.mass) == (0.340, 0.0029, 0.00517)
    assert paper.material.youngs_modulus == 26e6


def test_unknown_or_malformed_parameter_sets_are_refused(tmp_path):
    with pytest.raises(ParamsError, match="available"):
        load_params("no_such_set")
    bad = tmp_path / "prb3_bad.yaml"
    bad.write_text("beam: {k: -1}\n")
    with pytest.raises(ParamsError, match=r"beam\.k"):
        load_params(str(bad))
    fitted = tmp_path / "prb3_fit.yaml"
    fitted.write_text("name: fit\nbeam: {k: 0.0285, b: 0.006}\nrig: {foot_mass: 0.021}\n")
    p = load_params(str(fitted))
    assert (p.k, p.b, p.l2, p.rig["foot_mass"]) == (0.0285, 0.006, 0.02366, 0.021)


def test_one_registry_names_every_model():
    assert [model_family(n) for n in ("prb3", "rod10", "rod3g", "rod3gs")] == ["prb3", "rod", "rod", "rod"]
    assert canonical_model("rod") == "rod10" and canonical_model("prb3") == "prb3"
    assert is_rod("rod") and is_rod("rod5g") and not is_rod("prb3")
    assert beam_model("rod3g").name == "rod3g" and beam_model("prb3").name == "prb3"
    for bad in ("prb", "rod0", "rodx", "beam7", ""):
        with pytest.raises(UnknownModelError, match="unknown beam model") as err:
            model_family(bad)
        assert isinstance(err.value, BeambenchError) and isinstance(err.value, ValueError)


def _free_beam(params, twist_deg: float) -> tuple[mujoco.MjModel, mujoco.MjData]:
    spec = mujoco.MjSpec()
    spec.option.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    spec.option.timestep = 1e-4
    sites = add_beam(spec.worldbody, make_beam_model("prb3", params), twist_deg)
    spec.body(sites.tip_body).add_geom(
        type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.003, 0, 0], pos=[0, 0, -0.0635], mass=0.02
    )
    m = spec.compile()
    return m, mujoco.MjData(m)


def test_prb3_structure_masses_and_bending_axes(paper):
    m, d = _free_beam(paper, 90.0)
    mujoco.mj_forward(m, d)
    names = [m.joint(i).name for i in range(m.njnt)]
    assert names == ["beam_R1", "beam_R4", "beam_R2", "beam_R5", "beam_R3"]  # 3 bending + 2 twist
    beam_mass = sum(m.body(f"beam_link{i}").mass[0] for i in (2, 3))
    assert beam_mass == pytest.approx(paper.mass, rel=1e-9)
    assert m.body("beam_link3").mass[0] / beam_mass == pytest.approx(paper.l3 / paper.length)
    assert np.allclose(m.jnt_stiffness, paper.k) and np.allclose(m.dof_damping, paper.b)
    # bending axes (world, rest) are the section's width direction at 0°, 45°, 90°; twist axes along y
    axis = {n: d.xaxis[m.joint(n).id] for n in names}
    s = math.sqrt(0.5)
    assert np.allclose(np.abs(axis["beam_R1"]), [0, 0, 1], atol=1e-12)
    assert np.allclose(np.abs(axis["beam_R2"]), [s, 0, s], atol=1e-12)
    assert np.allclose(np.abs(axis["beam_R3"]), [1, 0, 0], atol=1e-12)
    assert np.allclose(np.abs(axis["beam_R4"]), [0, 1, 0]) and np.allclose(np.abs(axis["beam_R5"]), [0, 1, 0])
    assert np.allclose(d.site("beam_tip_site").xpos, [0, paper.length, 0])
    assert np.allclose(d.xmat[m.body("beam_tip").id].reshape(3, 3), np.eye(3))  # tip frame = clamp frame


def test_untwisted_prb3_merges_the_coincident_root_joints(paper):
    m, _ = _free_beam(paper, 0.0)
    assert m.njnt == 4 and m.joint("beam_R1R2").stiffness[0] == pytest.approx(paper.k / 2)


def test_free_vibration_loses_energy_monotonically(paper):
    m, d = _free_beam(paper, 90.0)
    d.qpos[:] = [0.2, -0.1, 0.15, 0.1, -0.2]
    energy = []
    for _ in range(15000):  # 1.5 s, no drive, gravity on (foot modes at 6 and 8 Hz, zeta 0.15-0.2)
        mujoco.mj_step(m, d)
        energy.append(d.energy.sum())
    e = np.array(energy)
    assert np.all(np.diff(e) <= 1e-12)
    assert e[0] - e[-1] > 0.5 * (e[0] - e.min())  # it really dissipates, not just stays put
    assert np.all(np.abs(d.qvel) < 1e-3)  # and comes to rest


def test_opposite_chirality_mirrors_the_tip_path(paper):
    """φ → −φ mirrors the beam across the y–z plane; with the drive mirrored (a half-period shift) the
    steady tip path is mirrored x → −x and travelled in the opposite sense."""
    f, T = 15.0, 1 / 15.0
    beam = make_beam_model("prb3", paper)
    runs = {}
    for phi in (90.0, -90.0):
        sim = ContactRigSim(beam, phi, gap_m=0.0055, timestep=1e-4)
        sim.set_frequency(f)
        runs[phi] = sim.advance_to(2.6)
    tq = np.linspace(2.4, 2.4 + T, 300)
    plus = interp_rows(runs[90.0].t, runs[90.0].channels["markers"][:, 1], tq + T / 2) * [-1, 1, 1]
    minus = interp_rows(runs[-90.0].t, runs[-90.0].channels["markers"][:, 1], tq)
    assert np.ptp(plus[:, 0]) > 2e-3  # a real orbit (stage stroke 4 mm)
    assert np.abs(plus - minus).max() < 1e-6

    def signed_area(p: np.ndarray) -> float:  # orbit in the x–z plane
        x, z = p[:, 0], p[:, 2]
        return 0.5 * float(np.sum(x * np.roll(z, -1) - np.roll(x, -1) * z))

    a_plus = signed_area(interp_rows(runs[90.0].t, runs[90.0].channels["markers"][:, 1], tq))
    a_minus = signed_area(minus)
    assert abs(a_plus) > 1e-8 and a_minus == pytest.approx(-a_plus, rel=1e-3)


def test_segmented_rod_runs_in_the_contact_rig_and_mirrors_with_chirality():
    """With the drive mirrored too (A → −A) the −φ rod's whole tip path, transients included, is the
    mirror image of the +φ one (this rod's response at 20 Hz is not periodic, so no half-period trick)."""
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.backends.sim import build_scene
    from beambench.session.slices import sim_slice

    scene = build_scene(sim_slice(parse_protocol("sweep: {frequencies: [1]}\nsim: {model: rod5}\n")))
    assert scene.physics.model.nv == 1 + 3 * 5 and scene.identity()["model"] == "rod5"
    beam = make_beam_model("rod5", load_params("paper", model="rod"))
    paths = {}
    for phi, amp in ((90.0, 2e-3), (-90.0, -2e-3)):
        sim = ContactRigSim(beam, phi, gap_m=0.0055, amplitude_m=amp)
        sim.set_frequency(20.0)
        paths[phi] = sim.advance_to(1.5).channels["markers"][:, 1]
    plus, minus = paths[90.0] * [-1, 1, 1], paths[-90.0]
    assert np.ptp(minus[:, 2]) > 1e-3  # the softer rod couples a real vertical motion
    assert np.abs(plus - minus).max() < 1e-6
