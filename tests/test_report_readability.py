"""The report read as a scientist: a table that fits the page, both sessions visible when they coincide,
uncertain senses marked, a note when nothing touched the plate, and no side effects on matplotlib."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from matplotlib import colors as mcolors
from matplotlib import image as mimage
from typer.testing import CliRunner

from beambench.analysis.figures.style import SESSION_COLORS
from beambench.analysis.report import SUMMARY_COLUMNS, summary_table
from beambench.analysis.synthetic import SynthSession, SynthStep, write_synthetic_session
from beambench.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("readable")
    touching = write_synthetic_session(
        d / "touching.h5",
        SynthSession(
            [SynthStep(12.0, 1), SynthStep(26.0, 2, touchdown_velocity_sign=-1, tangential_n=-0.2)],
            record_s=1.5,
            settle_s=0.3,
            seed=1,
        ),
    )
    twin = d / "twin.h5"  # the same session again: equal seeds give identical traces
    shutil.copy(touching, twin)
    apart = write_synthetic_session(
        d / "apart.h5",
        SynthSession([SynthStep(12.0, 0), SynthStep(30.0, 0)], record_s=1.5, settle_s=0.3, seed=4),
    )
    return touching, twin, apart


def _html_tables(html: str) -> list[str]:
    return re.findall(r"<table class=\"dataframe data\">(.*?)</table>", html, flags=re.S)


def test_per_step_table_is_a_readable_subset_with_units_and_links_the_full_csv(sessions, tmp_path):
    touching, _, _ = sessions
    res = runner.invoke(
        app, ["analyze", str(touching), "--out", str(tmp_path / "r"), "--no-write", "-q", "--figures", "none"]
    )
    assert res.exit_code == 0, res.output
    html = (tmp_path / "r" / "index.html").read_text()
    full = pd.read_csv(tmp_path / "r" / "steps.csv")
    per_step = html.split("<h2>Per-step results</h2>")[1]
    headers = re.findall(r"<th>([^<]*)</th>", _html_tables(per_step)[0])
    assert 5 <= len(headers) <= len(SUMMARY_COLUMNS) < len(full.columns)
    assert "drive (Hz)" in headers and "peak normal force (N)" in headers
    assert f"every column ({len(full.columns)}) is in <a href='steps.csv'>" in per_step
    assert "No contact anywhere" not in html


def test_a_session_without_any_contact_says_so_at_the_top(sessions, tmp_path):
    _, _, apart = sessions
    res = runner.invoke(app, ["analyze", str(apart), "--out", str(tmp_path / "r"), "--no-write", "-q"])
    assert res.exit_code == 0, res.output
    html = (tmp_path / "r" / "index.html").read_text()
    assert 0 <= html.index("No contact anywhere") < html.index("<h2>Provenance")


def test_sense_is_marked_uncertain_where_the_ellipse_fit_is_poor():
    table = pd.DataFrame(
        {
            "frequency_hz": [20.0, 10.0, 30.0],
            "tip_sense": ["cw", "ccw", ""],
            "tip_ellipse_r2": [0.3, 0.9, 0.1],
            "regime": ["1", "1/2", "none"],
        }
    )
    out = summary_table(table)
    assert out["drive (Hz)"].tolist() == [10.0, 20.0, 30.0]  # frequency order
    assert out["tip sense"].tolist() == ["ccw", "cw (uncertain)", ""]


def _pixels_near(png, color: str, tol: float = 0.12) -> int:
    img = mimage.imread(png)[..., :3]
    return int((np.abs(img - np.array(mcolors.to_rgb(color))).max(axis=-1) < tol).sum())


def test_equal_sessions_overlaid_both_show(sessions, tmp_path):
    """Two identical sessions: the first is drawn broad and pale underneath, the second dashed on top, so both
    colours cover the force traces (before, the second hid the first except in the legend)."""
    touching, twin, _ = sessions
    res = runner.invoke(app, ["compare", str(touching), str(twin), "--out", str(tmp_path / "c"), "--no-write", "-q"])
    assert res.exit_code == 0, res.output
    png = tmp_path / "c" / "forces.png"
    pale_first = mcolors.to_hex(0.45 * np.array(mcolors.to_rgb(SESSION_COLORS[0])) + 0.55)  # alpha 0.45 on white
    assert _pixels_near(png, pale_first, 0.08) > 1500
    assert _pixels_near(png, SESSION_COLORS[1]) > 1500


def test_the_report_leaves_matplotlib_and_pyplot_alone(sessions, tmp_path):
    touching, _, _ = sessions
    code = f"""
import sys, matplotlib
matplotlib.use("svg")
before = dict(matplotlib.rcParams)
from beambench.analysis.report import make_report
from beambench.analysis.session_analysis import analyze_session
from beambench.sinks.session_file.reader import read_session
make_report([analyze_session(read_session({str(touching)!r}))], {str(tmp_path / "r")!r})
assert matplotlib.get_backend() == "svg", matplotlib.get_backend()
assert dict(matplotlib.rcParams) == before
assert "matplotlib.pyplot" not in sys.modules
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "r" / "trajectories.png").is_file()
