"""Drift and hysteresis end to end on the sim: a contact protocol swept both ways with reference steps and two repeats runs
and analyses; hysteresis flags, spreads, path metrics and the drift table are in steps.csv and the report; with
the twin's thermal drift on the reference steps show a significant trend, with it off they do not.

The drift is time-compressed (a 5 mJ/K beam instead of the physical 9.3 J/K) so that a 13-step run of 13 s
warms the beam by ~13 K and softens it by ~13 %; the same equation as an hour-long run of the physical beam.
"""

from __future__ import annotations

import h5py
import pandas as pd
import pytest
from typer.testing import CliRunner

from beambench.cli import app

runner = CliRunner()
pytestmark = pytest.mark.slow

PROTOCOL = """
name: drift_{name}
rig: contact
backend: sim
sweep: {{frequencies: [10, 16], direction: both, repeats: 2}}
reference: {{frequency_hz: 12, every_steps: 1}}
settle_s: 0.4
record_s: 0.6
amplitude_mm: 2.0
sim: {{model: prb3, params: paper, plate_gap_mm: 1.0, seed: 1{drift}}}
"""
DRIFT = ", thermal_drift: {alpha_per_k: 0.01, tau_s: 1000, heat_capacity_j_per_k: 0.005}"


def _run(tmp_path, name: str, drift: str):
    proto = tmp_path / f"{name}.yaml"
    proto.write_text(PROTOCOL.format(name=name, drift=drift))
    res = runner.invoke(app, ["run", str(proto), "--rerun", "off", "--out", str(tmp_path), "--name", name])
    assert res.exit_code == 0, res.output
    return tmp_path / f"{name}.h5"


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("drift")
    return {"on": _run(d, "on", DRIFT), "off": _run(d, "off", "")}


def test_with_drift_on_the_report_has_the_trend_and_every_new_column(sessions):
    session = sessions["on"]
    args = ["-q", "--no-write", "--drift-correct", "--figures", "drift"]  # the drift figure is the one checked
    res = runner.invoke(app, ["analyze", str(session), *args])
    assert res.exit_code == 0, res.output
    out = session.with_name("on_report")
    steps = pd.read_csv(out / "steps.csv")
    assert len(steps) == 13  # (up 10, 16, down 10) x 2 repeats, a reference before each and one last
    assert set(steps["direction"]) == {"up", "down"} and (steps["kind"] == "reference").sum() == 7
    assert set(steps.loc[steps["kind"] == "sweep", "repeat"]) == {0, 1}
    for col in ("hysteresis", "hysteresis_delta", "repeats_agree", "tip_major_mm_std", "tip_major_mm_ci95_lo"):
        assert col in steps, col
    for col in ("tip_crossings", "tip_loop_sense", "tip_path_inverts", "motor_current_rms_a"):
        assert col in steps, col
    assert steps.loc[steps["frequency_hz"] == 10, "hysteresis"].notna().all()
    assert "tip_major_mm_drift_corrected" in steps

    drift = pd.read_csv(out / "drift.csv").set_index("metric")
    assert drift["significant"].any(), drift
    assert bool(drift.loc["tip_major_mm", "significant"])
    assert drift.loc["tip_major_mm", "trend_per_h"] < 0  # a softer beam moves less below resonance here
    assert (out / "drift.png").exists()
    html = (out / "index.html").read_text()
    assert "Drift at the reference steps" in html and "drift.png" in html
    with h5py.File(session, "r") as f:
        factor = float(f["general/sim_thermal_drift/stiffness_factor"][()])
    assert 0.8 < factor < 0.95  # the twin's truth: the beam did soften

    # the correction brings the repeats of a frequency closer (the later repeat ran on a softer beam)
    sweep10 = steps[(steps["kind"] == "sweep") & (steps["frequency_hz"] == 10) & (steps["direction"] == "up")]
    raw, fixed = sweep10["tip_major_mm"], sweep10["tip_major_mm_drift_corrected"]
    assert abs(fixed.iloc[1] - fixed.iloc[0]) < 0.5 * abs(raw.iloc[1] - raw.iloc[0])


def test_with_drift_off_no_reference_trend_is_significant(sessions):
    from beambench.analysis import analyze_session
    from beambench.analysis.drift import drift_table
    from beambench.analysis.figures.trajectories import shape_note
    from beambench.sinks.session_file.reader import read_session

    a = analyze_session(read_session(sessions["off"]))
    table = drift_table(a.table)
    assert len(table) == 5 and (table["n_reference"] == 7).all()
    assert not table["significant"].any(), table[["metric", "trend_per_h", "t_stat", "t_crit"]]
    with h5py.File(sessions["off"], "r") as f:
        assert "sim_thermal_drift" not in f["general"]

    # the trajectory panels' titles carry the path metrics of steps.csv
    for r in a.steps:
        row = a.table[a.table["step"] == r.index].iloc[0]
        note = shape_note(a, r, "foot")
        assert ("figure-8" in note) == (row["foot_crossings"] == 1)
        assert ("inverts" in note) == bool(row["foot_path_inverts"])
