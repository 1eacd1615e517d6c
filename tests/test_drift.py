"""Drift from reference steps (analysis.drift) and the twin's thermal-drift model (sim.models.thermal), each
checked against an independent computation: scipy's linregress for the trend, the closed-form first-order
response for the temperature, the compiled MuJoCo model's joint stiffness for the softening."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from beambench.acquisition.protocol.schema import parse_protocol
from beambench.analysis.drift import drift_corrected, drift_table, linear_trend
from beambench.cli import app
from beambench.common.yaml_config import ConfigError
from beambench.sim.models.thermal import ThermalParams, ThermalState

CONTACT = "rig: contact\nsweep: {frequencies: [10, 14]}\nsettle_s: 0.2\nrecord_s: 0.2\n"


def _table(ref_values: np.ndarray, sweep_values: np.ndarray | None = None, dt_s: float = 60.0) -> pd.DataFrame:
    """Reference, sweep, reference, … steps every ``dt_s`` (a per-step table as analyze_session makes)."""
    rows = []
    sweep_values = np.zeros(len(ref_values) - 1) if sweep_values is None else sweep_values
    for i, r in enumerate(ref_values):
        rows.append(dict(kind="reference", frequency_hz=12.0, t_settled_s=2 * i * dt_s, record_s=1.0, tip_major_mm=r))
        if i < len(sweep_values):
            rows.append(
                dict(
                    kind="sweep",
                    frequency_hz=20.0,
                    t_settled_s=(2 * i + 1) * dt_s,
                    record_s=1.0,
                    tip_major_mm=sweep_values[i],
                )
            )
    return pd.DataFrame(rows)


def test_the_trend_and_its_standard_error_are_linregress_s():
    from scipy import stats  # the independent reference (imported here: ~1 s, in the worker that runs this)

    rng = np.random.default_rng(1)
    t = np.sort(rng.uniform(0, 3, 12))
    y = 1.0 - 0.05 * t + rng.normal(0, 0.01, len(t))
    r, ref = linear_trend(t, y), stats.linregress(t, y)
    assert r["trend_per_h"] == pytest.approx(ref.slope, rel=1e-12)
    assert r["trend_se_per_h"] == pytest.approx(ref.stderr, rel=1e-10)
    assert r["p_value"] == pytest.approx(ref.pvalue, rel=1e-8)
    assert r["t_crit"] == pytest.approx(stats.t.ppf(0.975, 10))


def test_a_trend_beyond_the_noise_is_significant_and_none_is_not():
    rng = np.random.default_rng(2)
    n = 9  # references 2 min apart: 16 min
    hours = np.arange(n) * 120 / 3600
    drifting = drift_table(_table(1.2 - 0.3 * hours + rng.normal(0, 0.005, n))).set_index("metric")
    steady = drift_table(_table(1.2 + rng.normal(0, 0.005, n))).set_index("metric")
    assert bool(drifting.loc["tip_major_mm", "significant"])
    assert drifting.loc["tip_major_mm", "trend_per_h"] == pytest.approx(-0.3, abs=0.05)
    assert not bool(steady.loc["tip_major_mm", "significant"])
    assert abs(steady.loc["tip_major_mm", "t_stat"]) < steady.loc["tip_major_mm", "t_crit"]


def test_a_noiseless_trend_below_the_resolution_is_not_drift():
    hours = np.arange(6) * 120 / 3600
    t = drift_table(_table(1.0 + 1e-4 * hours)).set_index("metric")  # t → ∞, but 1e-5 mm over the session
    assert t.loc["tip_major_mm", "t_stat"] > 100 and not bool(t.loc["tip_major_mm", "significant"])


def test_fewer_than_three_references_give_no_trend():
    t = drift_table(_table(np.array([1.0, 0.9]))).set_index("metric")
    assert math.isnan(t.loc["tip_major_mm", "trend_per_h"]) and not bool(t.loc["tip_major_mm", "significant"])
    assert drift_table(_table(np.array([1.0, 0.9])).assign(kind="sweep")).empty


def test_drift_correction_removes_a_linear_drift_between_bracketing_references():
    n, slope = 5, -0.02  # per reference interval
    refs = 1.0 + slope * np.arange(n)
    sweep = 2.0 + slope * (np.arange(n - 1) + 0.5)  # halfway between references: half an interval's drift
    out = drift_corrected(_table(refs, sweep))
    corrected = out.loc[out["kind"] == "sweep", "tip_major_mm_drift_corrected"].to_numpy()
    assert corrected == pytest.approx(np.full(n - 1, 2.0), abs=1e-12)
    assert out.loc[out["kind"] == "reference", "tip_major_mm_drift_corrected"].to_numpy() == pytest.approx(1.0)


def test_the_beam_temperature_follows_the_first_order_solution():
    p = ThermalParams(alpha_per_k=0.01, tau_s=50.0, heat_capacity_j_per_k=2.0, heated_fraction=0.5)
    th = ThermalState(p, np.array([0]), np.array([1.0]))
    for _ in range(300):  # 30 s at 0.1 s chunks, 8 mW
        th.heat(0.008, 0.1)
    steady = 0.5 * 0.008 * 50 / 2.0
    assert th.rise_k == pytest.approx(steady * (1 - math.exp(-30 / 50)), rel=1e-9)
    assert th.factor == pytest.approx(1 - 0.01 * th.rise_k)
    assert th.heat_j == pytest.approx(0.5 * 0.008 * 30)


def test_the_contact_twin_softens_its_beam_hinges_as_it_warms_and_a_snapshot_undoes_it():
    from beambench.backends.sim import build_scene
    from beambench.session.slices import sim_slice

    proto = parse_protocol(
        CONTACT + "sim: {model: prb3, thermal_drift: {alpha_per_k: 0.02, tau_s: 500, heat_capacity_j_per_k: 0.01}}\n"
    )
    scene = build_scene(sim_slice(proto))
    th = scene.thermal
    assert th is not None and len(th.joints) == 5  # PRB3's hinges; the stage slider is not scaled
    k0 = scene.physics.model.jnt_stiffness[th.joints].copy()
    scene.set_frequency(14.0)
    scene.advance_to(0.5)
    snap = scene.snapshot()
    rise = th.rise_k
    scene.advance_to(1.0)
    assert th.rise_k > rise > 0.1  # milliwatts into 0.01 J/K: tenths of a kelvin per second
    factor = th.factor
    scene.advance_to(1.1)  # the next chunk runs at the stiffness of the temperature before it
    assert scene.physics.model.jnt_stiffness[th.joints] == pytest.approx(k0 * factor, rel=1e-12)
    assert factor < 1 - 0.02 * rise < 1
    scene.restore(snap)
    assert th.rise_k == rise
    scene.advance_to(0.6)
    assert scene.physics.model.jnt_stiffness[th.joints] == pytest.approx(k0 * (1 - 0.02 * rise), rel=1e-12)


def test_thermal_drift_is_off_by_default_and_checked():
    from beambench.backends.sim import build_scene
    from beambench.session.slices import sim_slice

    assert build_scene(sim_slice(parse_protocol(CONTACT))).thermal is None
    with pytest.raises(ConfigError, match=r"sim.thermal_drift.alpha_per_k.*less than or equal to 0.2"):
        parse_protocol(CONTACT + "sim: {thermal_drift: {alpha_per_k: 0.5}}\n", "p.yaml")
    with pytest.raises(ConfigError, match=r"sim.thermal_drift.tau.*unknown field"):
        parse_protocol(CONTACT + "sim: {thermal_drift: {tau: 60}}\n", "p.yaml")


def test_thermal_drift_on_the_walker_is_one_line_and_exit_2(tmp_path):
    proto = tmp_path / "w.yaml"
    proto.write_text("rig: walker\nsweep: {frequencies: [20]}\nsim: {thermal_drift: {alpha_per_k: 0.01}}\n")
    res = CliRunner().invoke(app, ["run", str(proto), "--rerun", "off", "--out", str(tmp_path)])
    assert res.exit_code == 2, res.output
    assert "sim.thermal_drift = {'alpha_per_k': 0.01}" in res.output and "contact only" in res.output
    assert "Traceback" not in res.output


def _drive(rig, calls, announce):
    """Drive a sim rig as the runner does (arm, per step a command and its waits); the mocap samples and the
    beam's final thermal state."""
    from beambench.acquisition.capabilities import MotorLimits

    rig.open()
    rig.motor.arm(MotorLimits(max_frequency_hz=40, max_current_a=10, amplitude_mm=2.0))
    if announce is not None:
        rig.anticipate(announce)
    batches = []
    for hz, waits in calls:
        rig.motor.set_frequency(hz)
        for w in waits:
            rig.clock.wait(w)
            batches.append(rig.mocap.read().columns["data"])
    state = rig.after_run()["sim_thermal_drift"]
    rig.close()
    return np.concatenate(batches), state


def test_thermal_drift_gives_the_same_data_computed_ahead_or_on_demand():
    from beambench.backends.sim import SimRig
    from beambench.session.slices import sim_slice

    proto = parse_protocol(
        CONTACT + "sim: {model: prb3, seed: 4, thermal_drift: {alpha_per_k: 0.02, heat_capacity_j_per_k: 0.01}}\n"
    )
    announced = [(10.0, [0.2, 0.2]), (14.0, [0.2, 0.2])]
    actual = [(10.0, [0.2, 0.2]), (14.0, [0.2, 0.1, 0.1])]  # leaves the schedule: the lookahead is undone
    ahead, state_ahead = _drive(SimRig(sim_slice(proto)), actual, announce=announced)
    on_demand, state = _drive(SimRig(sim_slice(proto), prefetch=False), actual, announce=None)
    np.testing.assert_array_equal(ahead, on_demand)
    assert state_ahead == state and state["stiffness_factor"] < 0.995
