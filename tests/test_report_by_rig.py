"""Reports by rig, through the figure registry: a walker report has walker figures and no contact-rig figure, a
release report has the decay figure and a table with the natural frequency and the damping ratio, no shipped
protocol's report writes a warning to stderr; the decay fit and the stance detection recover known values."""

from __future__ import annotations

import gc
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from beambench.analysis.figures import FIGURES, FigureRegistry
from beambench.analysis.figures.ellipse import unwrapped_tilt
from beambench.analysis.release import fit_decay, free_response
from beambench.analysis.walking import foot_stance
from beambench.cli import app

runner = CliRunner()
PROTOCOLS = Path(__file__).resolve().parents[1] / "protocols"
CONTACT_ONLY = {"contact_frequency", "drift", "forces", "contact_direction"}
WALKER_ONLY = {"walking_speed", "body_trajectory", "gait", "tracking"}


def _short(name: str, tmp, **changes: object) -> str:
    """A shipped protocol cut short (fewer steps, shorter windows): the same scene and devices, seconds to run."""
    import yaml

    proto = yaml.safe_load((PROTOCOLS / f"{name}.yaml").read_text())
    proto.update(changes)
    proto.get("sim", {}).pop("segments", None)
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump(proto))
    return str(path)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """Short sim sessions of the three shipped rigs."""
    d = tmp_path_factory.mktemp("byrig")
    protos = {
        "contact": _short("contact_sweep", d, sweep={"frequencies": [21, 33]}, settle_s=0.4, record_s=0.5),
        "walker": _short("walker_sweep", d, sweep={"frequencies": [23, 65]}, settle_s=0.4, record_s=0.6),
        "release": _short("release_test", d),
    }
    out = {}
    for rig, proto in protos.items():
        res = runner.invoke(app, ["run", proto, "--out", str(d), "--name", rig, "--rerun", "off"])
        assert res.exit_code == 0, res.output
        out[rig] = d / f"{rig}.h5"
    return out


def _report(session, tmp_path) -> tuple[set[str], str]:
    """Analyse a session with every warning recorded; the PNGs written and index.html."""
    out = tmp_path / "r"
    gc.collect()  # what earlier tests in this worker left for the collector warns now, not inside the analysis
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = runner.invoke(app, ["analyze", str(session), "--out", str(out), "--no-write", "-q"])
    assert res.exit_code == 0, res.output
    assert not [str(w.message) for w in caught]
    return {p.stem for p in out.glob("*.png")}, (out / "index.html").read_text()


def test_the_registry_picks_figures_by_rig():
    by_rig = {rig: {s.key for s in FIGURES.for_rigs({rig})} for rig in ("contact", "walker", "release")}
    assert CONTACT_ONLY | {"trajectories", "ellipse", "frequency", "sync"} == by_rig["contact"]
    assert WALKER_ONLY | {"trajectories", "ellipse", "frequency", "sync"} == by_rig["walker"]
    assert by_rig["release"] == {"release_decay", "sync"}
    mixed = {s.key for s in FIGURES.for_rigs({"contact", "walker"})}  # a compare of two rigs: what both have
    assert mixed == {"trajectories", "ellipse", "frequency", "sync"}


def test_a_registry_refuses_a_figure_for_no_rig_and_a_second_figure_of_the_same_name():
    reg = FigureRegistry()

    @reg.add("a", scenes=lambda s: s.walks, caption="A.")
    def _a(analyses, path, options):
        return None

    assert reg.keys() == ["a"] and reg["a"].caption_for("walker") == "A." and reg["a"].rigs == {"walker"}
    with pytest.raises(ValueError, match="registered twice"):
        reg.add("a", scenes=lambda s: s.walks, caption="again")
    with pytest.raises(ValueError, match="applies to no rig of the scene catalogue"):
        reg.add("b", scenes=lambda s: s.walks and s.plate, caption="B.")


def test_walker_report_has_walker_figures_and_no_contact_rig_figure(sessions, tmp_path):
    pngs, html = _report(sessions["walker"], tmp_path)
    assert (WALKER_ONLY - {"tracking"}) | {"trajectories", "ellipse", "frequency"} <= pngs  # tracking: track: runs
    assert not pngs & (CONTACT_ONLY | {"release_decay", "sync"})  # sync: the sim's clock residuals are flat
    assert "No contact anywhere" not in html and "contact regime" not in html
    assert "body speed (mm/s)" in html


def test_release_report_has_the_decay_figure_and_frequency_and_damping_in_its_table(sessions, tmp_path):
    pngs, html = _report(sessions["release"], tmp_path)
    assert pngs == {"release_decay"}
    per_step = html.split("<h2>Per-step results</h2>")[1]
    cells = re.findall(r"<t[hd]>([^<]*)</t[hd]>", per_step)
    headers = cells[: len(cells) // 2]
    row = dict(zip(headers, cells[len(headers) :]))
    fn, zeta = float(row["natural frequency (Hz)"]), float(row["damping ratio ζ"])
    # the table shows the decay fit of the recorded tip (4 significant digits), and that fit explains the record
    from beambench.analysis.release import step_decay
    from beambench.analysis.session_analysis import analyze_session
    from beambench.sinks.session_file.reader import read_session

    (step,) = analyze_session(read_session(sessions["release"])).steps
    fitted = step_decay(step)
    assert fitted is not None
    decay = fitted[1]
    assert fn == pytest.approx(decay.natural_frequency_hz, rel=1e-3)
    assert zeta == pytest.approx(decay.damping_ratio, rel=1e-3)
    assert float(row["fit R²"]) == pytest.approx(decay.r2, abs=1e-3) and decay.r2 > 0.95
    assert float(row["deflection at release (mm)"]) > 3  # the 200 g load's deflection
    assert "measured (Hz)" not in html


def test_contact_report_is_the_contact_figures_without_the_sims_flat_sync(sessions, tmp_path):
    pngs, _ = _report(sessions["contact"], tmp_path)
    # drift: only with reference steps (this protocol has none)
    assert pngs == (CONTACT_ONLY - {"drift"}) | {"trajectories", "ellipse", "frequency"}


def test_the_release_report_writes_nothing_to_stderr(sessions, tmp_path):
    """In a fresh interpreter, as a user runs it (it wrote a matplotlib UserWarning)."""
    for rig in ("release",):  # the others: every warning is recorded in _report
        res = subprocess.run(
            [sys.executable, "-m", "beambench", "analyze", str(sessions[rig]), "-o", str(tmp_path / rig), "-q"],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert res.returncode == 0 and res.stderr == "", res.stderr


@pytest.mark.parametrize("fn,zeta", [(40.0, 0.05), (35.0, 0.5), (35.0, 1.0)])
def test_the_decay_fit_recovers_natural_frequency_and_damping(fn, zeta):
    """Under- to critically damped at the mocap's 360 frames/s and 0.1 mm noise (a strongly over-damped decay
    shows only its slow pole, so fₙ and ζ are not separately determined there)."""
    rng = np.random.default_rng(0)
    t = np.arange(0, 1.0, 1 / 360)
    t_rel = 0.1013
    x = np.where(t < t_rel, 13.0, free_response(np.maximum(t - t_rel, 0), 13.0, fn, zeta))
    d = fit_decay(t, x + rng.normal(0, 0.1, len(t)))
    assert d.natural_frequency_hz == pytest.approx(fn, rel=0.08)
    assert d.damping_ratio == pytest.approx(zeta, rel=0.08)
    assert d.release_s == pytest.approx(t_rel, abs=1 / 360)
    assert np.isnan(d.damped_frequency_hz) == (zeta >= 1)


def test_stance_is_where_the_foot_is_near_the_ground():
    t = np.arange(0, 1, 1e-3)
    h = np.clip(2.0 * np.sin(2 * np.pi * 5 * t), 0, None)  # on the ground half of each cycle
    st = foot_stance(t, h, ground_mm=0.0, within_mm=0.01)
    assert st.duty_factor == pytest.approx(0.5, abs=0.01)
    assert np.allclose(st.touchdown_s, [0.1, 0.3, 0.5, 0.7, 0.9], atol=2e-3)
    wide = foot_stance(t, h, ground_mm=0.0, within_mm=1.0)  # within 1 mm: also the lowest sixth of each swing
    assert wide.duty_factor == pytest.approx(0.5 + np.arcsin(0.5) / np.pi, abs=0.01)


def test_tilt_is_unwrapped_through_vertical():
    tilt = pd.Series([3.0, 40.0, 80.0, -85.0, -40.0, 5.0])  # an axis turning through vertical to horizontal
    assert unwrapped_tilt(tilt).tolist() == [3.0, 40.0, 80.0, 95.0, 140.0, 185.0]
