"""``beambench analyze`` / ``compare`` on real session files: report folder, CSV, HTML, errors."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from beambench.analysis.synthetic import (
    SynthSession,
    SynthStep,
    write_synthetic_session,
)
from beambench.cli import app
from beambench.sinks.session_file.reader import read_processing

runner = CliRunner()


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("rep")
    a = write_synthetic_session(
        d / "sim_like.h5",
        SynthSession(
            [
                SynthStep(12.0, 1),
                SynthStep(26.0, 2, touchdown_velocity_sign=-1, tangential_n=-0.2),
                SynthStep(40.0, 3),
                SynthStep(8.0, 0),
            ],
            record_s=1.5,
            settle_s=0.3,
            mocap_dropout=0.02,
            seed=1,
        ),
    )
    b = write_synthetic_session(
        d / "rig_like.h5",
        SynthSession(
            [SynthStep(12.0, 1, clockwise=False), SynthStep(26.0, 1), SynthStep(40.0, 2)],
            record_s=1.5,
            settle_s=0.3,
            seed=2,
        ),
    )
    w = write_synthetic_session(
        d / "walker.h5",
        SynthSession(
            [SynthStep(23.0, 0, body_speed_mm_s=-35.0), SynthStep(65.0, 0, body_speed_mm_s=150.0)],
            rig="walker",
            record_s=1.5,
            seed=3,
        ),
    )
    return a, b, w


def _imgs(html: str) -> list[str]:
    return re.findall(r"<img src='([^']+)'", html)


def test_analyze_writes_a_report_and_processing(sessions):
    a, _, _ = sessions
    res = runner.invoke(app, ["analyze", str(a), "-q"])
    assert res.exit_code == 0, res.output
    out = a.with_name("sim_like_report")
    assert res.output.strip().endswith(str(out / "index.html"))
    html = (out / "index.html").read_text()
    for name in ("trajectories", "contact_frequency", "forces", "frequency", "ellipse", "contact_direction", "sync"):
        png = out / f"{name}.png"
        assert png.is_file() and png.stat().st_size > 10_000 and f"{name}.png" in _imgs(html)
    assert "walking_speed.png" not in html  # not a walker session
    for text in ("synthetic_contact", "synthetic", "beambench.analysis.synthetic", "steps.csv", "protocol YAML"):
        assert text in html
    csv = pd.read_csv(out / "steps.csv")
    assert csv["regime"].fillna("").tolist() == ["1", "1/2", "1/3", "none"]
    assert read_processing(a, "steps")["regime"].tolist() == ["1", "1/2", "1/3", "none"]


def test_force_traces_at_chosen_frequencies_and_custom_out(sessions, tmp_path):
    """Also ``--figures``: only the figure asked for is drawn, and the page shows just that one."""
    a, _, _ = sessions
    args = ["--force-at", "26,40", "--no-write", "-q", "--figures", "forces"]
    res = runner.invoke(app, ["analyze", str(a), "--out", str(tmp_path / "r"), *args])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "r" / "forces.png").is_file()
    assert sorted(p.name for p in (tmp_path / "r").glob("*.png")) == ["forces.png"]
    assert _imgs((tmp_path / "r" / "index.html").read_text()) == ["forces.png"]
    res = runner.invoke(app, ["analyze", str(a), "--out", str(tmp_path / "n"), "--no-write", "-q", "--figures", "none"])
    assert res.exit_code == 0, res.output
    assert not list((tmp_path / "n").glob("*.png")) and (tmp_path / "n" / "steps.csv").is_file()
    assert _imgs((tmp_path / "n" / "index.html").read_text()) == []


def test_compare_overlays_two_sessions(sessions, tmp_path):
    a, b, _ = sessions
    figures = "trajectories,contact_frequency,forces"  # the ones checked below (compare draws all by default)
    res = runner.invoke(
        app, ["compare", str(a), str(b), "--out", str(tmp_path / "cmp"), "--no-write", "-q", "--figures", figures]
    )
    assert res.exit_code == 0, res.output
    csv = pd.read_csv(tmp_path / "cmp" / "steps.csv")
    assert set(csv["session"]) == {"sim_like", "rig_like"}
    assert len(csv) == 7
    rig = csv[csv["session"] == "rig_like"]
    assert rig["regime"].tolist() == ["1", "1", "1/2"]
    html = (tmp_path / "cmp" / "index.html").read_text()
    assert html.count("<h3>sim_like</h3>") >= 2 and html.count("<h3>rig_like</h3>") >= 2
    assert {"trajectories.png", "contact_frequency.png", "forces.png"} <= set(_imgs(html))


def test_walker_report_has_walking_speed(sessions, tmp_path):
    _, _, w = sessions
    res = runner.invoke(app, ["analyze", str(w), "--out", str(tmp_path / "w"), "-q", "--figures", "walking_speed"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "w" / "walking_speed.png").is_file()
    csv = pd.read_csv(tmp_path / "w" / "steps.csv")
    assert np.allclose(csv["body_speed_mm_s"], [-35.0, 150.0], atol=1.5)


def test_a_missing_session_is_said_before_an_unwritable_report_folder(sessions):
    """The input is checked first: a missing session with --out somewhere unwritable names the session."""
    for args in (["analyze", "/nonexistent/x.h5"], ["compare", str(sessions[0]), "/nonexistent/y.h5"]):
        res = runner.invoke(app, [*args, "-q", "--out", "/proc/x"])
        lines = [ln for ln in res.output.splitlines() if ln.strip()]
        assert res.exit_code == 2 and len(lines) == 1 and "/nonexistent/" in lines[0] and "no such file" in lines[0], (
            lines
        )


@pytest.mark.parametrize(
    "args,needle",
    [
        (["analyze", "/nonexistent/x.h5"], "no such file"),
        (["analyze", "{bad}"], "not a beambench session"),
        (["analyze", "{good}", "--force-at", "abc"], "--force-at"),
        (["analyze", "{good}", "--up", "w"], "--up"),
        (["analyze", "{good}", "--figures", "forces,bogus"], "not a figure: bogus"),
        (["analyze", "{good}", "--figures", "walking_speed"], "walking_speed not drawn for contact sessions"),
        (["compare", "{good}", "/nonexistent/y.h5"], "no such file"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(sessions, tmp_path, args, needle):
    bad = tmp_path / "bad.h5"
    bad.write_text("not hdf5")
    args = [x.replace("{bad}", str(bad)).replace("{good}", str(sessions[0])) for x in args]
    res = runner.invoke(app, [*args, "-q", "--no-write", "--out", str(tmp_path / "o")])
    assert res.exit_code == 2
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in res.output
