"""Whole-session analysis on real HDF5 files written by SessionWriter from synthetic batches with known truth."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration
from beambench.analysis.session_analysis import (
    analyze_session,
    contacts_table,
    resample_session,
    session_calibration,
    write_results,
)
from beambench.analysis.synthetic import (
    SynthClock,
    SynthSession,
    SynthStep,
    write_synthetic_session,
)
from beambench.sinks.session_file.reader import read_processing, read_session

CLOCKS = {
    "mocap": SynthClock(offset_s=0.005, drift_ppm=50.0, jitter_s=0.0004),
    "loadcell": SynthClock(offset_s=-0.012, drift_ppm=-30.0, jitter_s=0.0004),
    "motor": SynthClock(offset_s=0.25, drift_ppm=10.0, jitter_s=0.001),
}
STEPS = [
    SynthStep(
        10.0, 1, major_mm=3.0, minor_mm=1.0, tilt_deg=20.0, clockwise=False, touchdown_velocity_sign=1, tangential_n=0.2
    ),
    SynthStep(
        20.0,
        2,
        major_mm=2.0,
        minor_mm=0.8,
        tilt_deg=-10.0,
        clockwise=True,
        touchdown_velocity_sign=-1,
        tangential_n=-0.2,
    ),
    SynthStep(
        30.0, 3, major_mm=2.5, minor_mm=0.5, tilt_deg=5.0, clockwise=True, touchdown_velocity_sign=1, tangential_n=0.3
    ),
    SynthStep(15.0, 0),
    SynthStep(12.0, -1, tangential_n=-0.1),
]
LABELS = ["1", "1/2", "1/3", "none", "continuous"]


@pytest.fixture(scope="module")
def contact_session(tmp_path_factory):
    # a calibration that is not the default, so the stored one must be used
    sens = np.array([[21000.0, 300.0], [19000.0, -200.0], [400.0, 20500.0], [-300.0, 19500.0]])
    cal = LoadCellCalibration(
        np.array([900.0, -500.0, 300.0, 100.0]), np.ones(4), np.linalg.pinv(sens), sens, "test plate"
    )
    cfg = SynthSession(STEPS, clocks=CLOCKS, mocap_dropout=0.05, occlusion=0.03, calibration=cal, record_s=2.0, seed=11)
    path = write_synthetic_session(tmp_path_factory.mktemp("s") / "contact.h5", cfg)
    session = read_session(path)
    return path, session, analyze_session(session)


def test_per_step_results_match_the_truth(contact_session):
    _, _, a = contact_session
    t = a.table
    assert len(t) == len(STEPS)
    assert t["regime"].tolist() == LABELS
    assert np.allclose(t["measured_frequency_hz"], [s.frequency_hz for s in STEPS], atol=0.01)
    assert np.allclose(t["stage_amplitude_mm"], 2.0, rtol=0.02)
    assert np.allclose(t["contacts_per_cycle"].iloc[:3], [1, 1 / 2, 1 / 3], atol=0.06)
    assert t["n_contacts"].iloc[3] == 0
    for i, s in enumerate(STEPS[:3]):
        row = t.iloc[i]
        assert row["tip_major_mm"] == pytest.approx(s.major_mm, rel=0.03)
        assert row["tip_minor_mm"] == pytest.approx(s.minor_mm, rel=0.05)
        assert row["tip_tilt_deg"] == pytest.approx(s.tilt_deg, abs=1.5)
        assert row["tip_sense"] == ("cw" if s.clockwise else "ccw")
        assert row["touchdown_direction"] == s.touchdown_velocity_sign
        assert row["tangential_sign"] == np.sign(s.tangential_n)
    assert t["tangential_sign"].iloc[4] == -1  # continuous contact, pushing backwards
    assert a.calibration_source == "test plate"
    assert a.frame is not None and a.frame.drive[0] > 0.999 and a.frame.up[2] > 0.999


def test_clock_fits_align_mocap_and_loadcells(contact_session):
    a = contact_session[2]
    fm, fl = a.fits["mocap"], a.fits["loadcell"]
    assert fm.drift_ppm == pytest.approx(50.0, abs=3.0)
    assert fl.drift_ppm == pytest.approx(-30.0, abs=3.0)
    probe = np.linspace(1.0, 12.0, 500)  # true times
    dev_m = 0.005 + (1 + 50e-6) * probe
    dev_l = -0.012 + (1 - 30e-6) * probe
    err_ms = (fm.to_host_ns(dev_m) - fl.to_host_ns(dev_l)) / 1e6
    assert np.max(np.abs(err_ms)) <= 0.5
    # the encoder→marker delay cross-check sees no lag (both clocks fitted) within a millisecond
    assert abs(a.delay.delay_s) < 1e-3


def test_results_are_stored_in_processing(contact_session, tmp_path):
    path, _, a = contact_session
    write_results(a)
    steps = read_processing(path, "steps")
    assert steps["regime"].tolist() == LABELS
    assert np.allclose(steps["contacts_per_cycle"], a.table["contacts_per_cycle"], equal_nan=True)
    sync = read_processing(path, "sync")
    assert set(sync["stream"]) == {"mocap", "loadcell", "motor"}
    contacts = read_processing(path, "contacts")
    assert len(contacts) == len(contacts_table(a)) > 0
    assert contacts["touchdown"].sum() == a.table["n_contacts"].sum()
    delay = read_processing(path, "encoder_marker_delay")
    assert abs(float(delay["delay_s"].iloc[0])) < 1e-3
    # raw data untouched: reading the session again gives the same acquisition
    again = read_session(path)
    assert np.array_equal(
        again.streams["loadcell"].columns["data"], contact_session[1].streams["loadcell"].columns["data"]
    )
    assert session_calibration(again.general).source == "test plate"


def test_resampled_notebook_frame(contact_session):
    _, session, _ = contact_session
    df = resample_session(session, rate_hz=500.0)
    assert {"mocap/stage_x", "mocap/foot_z", "loadcell/normal_n", "motor/position"} <= set(df.columns)
    dt = np.diff(df.index.to_numpy())
    assert np.allclose(dt, 1 / 500.0, atol=1e-9)
    assert df["loadcell/normal_n"].max() == pytest.approx(1.5, rel=0.05)


def test_walker_body_speed(tmp_path):
    steps = [SynthStep(23.0, 0, body_speed_mm_s=-35.0), SynthStep(65.0, 0, body_speed_mm_s=156.3)]
    cfg = SynthSession(steps, rig="walker", clocks=CLOCKS, mocap_dropout=0.05, record_s=2.0, seed=2)
    a = analyze_session(read_session(write_synthetic_session(tmp_path / "walker.h5", cfg)))
    assert a.rig == "walker"
    assert a.table["body_speed_mm_s"].tolist() == pytest.approx([-35.0, 156.3], abs=1.0)
    assert np.allclose(a.table["motor_frequency_hz"], [23.0, 65.0], atol=0.05)
    assert "foot_left" in a.steps[0].paths and a.table["foot_left_sense"].iloc[0] == "cw"


def test_natnet_echo_exchanges_measure_the_mocap_latency(tmp_path):
    clocks = dict(CLOCKS, mocap=SynthClock(offset_s=0.005, drift_ppm=50.0, jitter_s=0.0004, latency_s=0.004))
    cfg = SynthSession(STEPS[:2], clocks=clocks, record_s=2.0, natnet_echo=True, seed=4)
    a = analyze_session(read_session(write_synthetic_session(tmp_path / "echo.h5", cfg)))
    echo, hull = a.fits["mocap_echo"], a.fits["mocap"]
    assert echo.method == "echo" and echo.drift_ppm == pytest.approx(50.0, abs=20.0)
    probe = np.linspace(1.0, 5.0, 50)
    dev = 0.005 + (1 + 50e-6) * probe
    # the echo fit puts frames at their true time; one-way stamps carry the 4 ms link latency
    assert np.max(np.abs(echo.to_host_ns(dev) - probe * 1e9)) < 0.2e6
    latency_ms = float(np.median(hull.to_host_ns(dev) - echo.to_host_ns(dev))) / 1e6
    assert latency_ms == pytest.approx(4.0, abs=0.3)
    assert "mocap_echo" in set(a.sync_table["stream"])


def test_a_cut_off_session_is_analysed_up_to_its_last_sample(tmp_path):
    import h5py

    cfg = SynthSession(STEPS[:2], record_s=2.0, seed=6)
    path = write_synthetic_session(tmp_path / "killed.h5", cfg)
    with h5py.File(path, "r+") as f:  # as a SIGKILL during step 2 leaves it: no end time, still running
        row = f["steps"][1]
        row["t_end_ns"], row["status"] = -1, b"running"
        f["steps"][1] = row
    a = analyze_session(read_session(path))
    assert a.table["status"].tolist() == ["done", "running"]
    assert a.table["record_s"].iloc[1] == pytest.approx(2.2, abs=0.05)  # up to the last sample
    assert a.table["regime"].tolist() == ["1", "1/2"]
