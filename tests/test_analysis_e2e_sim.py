"""End to end on the simulated rig: ``beambench run`` → ``beambench analyze`` → checks against the raw file.

The contact ratio in the report must equal an independent count: force peaks found with
``scipy.signal.find_peaks`` in the raw load-cell counts read straight from the HDF5 file (no calibration, no
clock fits, no hysteresis — a different route to the same number).
"""

from __future__ import annotations

from fractions import Fraction

import h5py
import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from beambench.cli import app

runner = CliRunner()
pytestmark = pytest.mark.slow

PROTOCOL = """
name: e2e_contact
rig: contact
backend: sim
sweep: {frequencies: [14, 24, 32, 38]}
settle_s: 0.6
record_s: 1.6
amplitude_mm: 2.0
limits: {max_frequency_hz: 40, max_current_a: 10, max_amplitude_mm: 3}
sim: {model: prb3, params: paper, plate_gap_mm: 1.0, twist_deg: 90, noise: true, seed: 3}
"""


def independent_ratios(path) -> list[float]:
    """Force peaks per drive cycle in each step's record window, from raw counts and raw host stamps."""
    from scipy.signal import find_peaks

    with h5py.File(path, "r", libver="latest", swmr=True) as f:
        counts = f["acquisition/loadcell/data"][()].astype(float)
        t = f["acquisition/loadcell/host_time_ns"][()]
        steps = f["steps"][()]
    # load on the plate shows as a deviation of any channel from its resting value
    activity = np.abs(counts - np.median(counts, axis=0)).sum(axis=1)
    base = np.median(activity)
    spread = 1.4826 * np.median(np.abs(activity - base))
    out = []
    for s in steps:
        sel = (t >= s["t_settled_ns"]) & (t < s["t_end_ns"])
        f_hz = float(s["frequency_hz"])
        peaks, _ = find_peaks(activity[sel], height=base + 30 * spread, distance=int(0.5 * 1000 / f_hz))
        duration = (s["t_end_ns"] - s["t_settled_ns"]) / 1e9
        out.append(len(peaks) / (duration * f_hz))
    return out


def nearest_label(ratio: float) -> str:
    if ratio < 0.05:
        return "none"
    return str(Fraction(1, max(1, round(1 / ratio)))) if ratio <= 1.1 else str(round(ratio))


def test_contact_sweep_ratio_equals_independent_peak_count(tmp_path):
    proto = tmp_path / "e2e.yaml"
    proto.write_text(PROTOCOL)
    res = runner.invoke(app, ["run", str(proto), "--rerun", "off", "--out", str(tmp_path), "--name", "gap1"])
    assert res.exit_code == 0, res.output
    session = tmp_path / "gap1.h5"
    res = runner.invoke(app, ["analyze", str(session), "-q", "--figures", "none"])  # the table is what is checked
    assert res.exit_code == 0, res.output
    report = pd.read_csv(tmp_path / "gap1_report" / "steps.csv")
    peaks = independent_ratios(session)
    assert len(report) == len(peaks) == 4
    for (_, row), ratio in zip(report.iterrows(), peaks):
        assert row["contacts_per_cycle"] == pytest.approx(ratio, abs=0.1), (row["frequency_hz"], row["regime"], ratio)
        assert row["regime"] == nearest_label(ratio)
    # the sweep crosses from one contact per cycle to one per two cycles (paper Fig. 1b, at a different f)
    assert report["regime"].iloc[0] == "1" and report["regime"].iloc[-1] == "1/2"
    # the stage follows the command: the measured drive frequency and amplitude are the protocol's
    assert np.allclose(report["measured_frequency_hz"], report["frequency_hz"], atol=0.1)
    assert np.allclose(report["stage_amplitude_mm"], 2.0, rtol=0.02)
