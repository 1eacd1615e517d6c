"""Report figures read as a lab user reads them: every mark on an axis means what the axis says, titles name the
point they show and claim nothing the data does not hold. Each test checks the data a figure is built from
(its axes, artists, labels and titles), drawn from synthetic sessions."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.collections import PolyCollection

from beambench.analysis.session_analysis import SessionAnalysis, analyze_session
from beambench.analysis.synthetic import SynthSession, SynthStep, write_synthetic_session
from beambench.sinks.session_file.reader import read_session


def _analysis(path) -> SessionAnalysis:
    return analyze_session(read_session(path))


@pytest.fixture(scope="module")
def walker(tmp_path_factory) -> SessionAnalysis:
    d = tmp_path_factory.mktemp("walker")
    steps = [SynthStep(f, body_speed_mm_s=0.3 * f - 6) for f in (5, 10, 15, 20, 23, 30, 35, 40, 50, 57, 65)]
    cfg = SynthSession(steps, rig="walker", record_s=1.0, settle_s=0.2, seed=3)
    return _analysis(write_synthetic_session(d / "walker.h5", cfg))


def test_gait_stance_bars_are_not_drawn_on_the_height_axis(walker):
    from beambench.analysis.figures.gait import gait_figure

    fig = gait_figure([walker])
    assert fig is not None
    heights = [ax for ax in fig.axes if "height" in ax.get_ylabel()]
    strips = [ax for ax in fig.axes if ax.get_title(loc="left") == "on the ground"]
    assert len(heights) == len(strips) >= 2
    for ax in heights:  # a height axis in mm carries heights only: no bar at a made-up negative height
        assert not [c for c in ax.collections if isinstance(c, PolyCollection)]
    for ax in strips:  # the bars live on their own strip, a row per foot, no mm scale
        assert [t.get_text() for t in ax.get_yticklabels()] == ["left foot", "right foot"]
        assert "mm" not in ax.get_ylabel()
        assert any(isinstance(c, PolyCollection) for c in ax.collections)


def test_body_trajectory_shows_a_few_named_steps_with_the_paper_points(walker):
    from beambench.analysis.figures.body_trajectory import MAX_LINES, body_figure

    fig = body_figure([walker])
    assert fig is not None
    ax = fig.axes[0]
    lines = [ln for ln in ax.get_lines() if len(ln.get_xdata()) > 2]
    assert 3 <= len(lines) <= MAX_LINES < len(walker.steps)  # not one line per step
    labels = [ln.get_label() for ln in lines]
    assert any(s.startswith("23 Hz") for s in labels) and any(s.startswith("65 Hz") for s in labels)
    assert f"{len(lines)} of {len(walker.steps)} steps" in ax.get_title()


@pytest.fixture(scope="module")
def contact(tmp_path_factory) -> SessionAnalysis:
    """Contact sweep at the sim's 0.1 mm mocap noise: continuous contact (a flat foot path) at 3-9 Hz, one contact
    per cycle above."""
    d = tmp_path_factory.mktemp("contact")
    steps = [SynthStep(f, contact_every=-1) for f in (3.0, 5.0, 7.0, 9.0)]
    steps += [SynthStep(f, contact_every=1) for f in (16.0, 20.0)]
    cfg = SynthSession(steps, record_s=2.0, settle_s=0.3, mocap_noise_m=1e-4, seed=5)
    return _analysis(write_synthetic_session(d / "contact.h5", cfg))


def test_flat_paths_have_no_crossings_counted_on_the_mocap_noise(contact):
    from beambench.analysis.figures.trajectories import shape_note

    t = contact.table.set_index("frequency_hz")
    assert 0.1 < t["path_noise_mm"].iloc[0] < 0.2  # two markers' 0.1 mm noise per axis: √2 × 0.1 mm
    flat = t.loc[[3.0, 5.0, 7.0, 9.0]]
    assert (flat["foot_crossings"] == 0).all(), flat["foot_crossings"]
    assert (flat["foot_loop_sense"] == "").all()
    for r in contact.steps:
        note = shape_note(contact, r, "foot")
        assert "crossings" not in note
        if r.frequency_hz < 10:
            assert note == " · flat"
    assert set(t.loc[[16.0, 20.0], "tip_loop_sense"]) <= {"cw", "ccw"}  # real loops keep their sense


def test_the_twist_sweep_title_names_the_tip_and_the_drive_frequency(tmp_path):
    import pandas as pd
    from matplotlib.figure import Figure

    from beambench.studies.sweep.figure import plot_sweep
    from beambench.studies.sweep.run import SweepSpec

    spec = SweepSpec.model_validate(
        {
            "name": "twist_sweep",
            "scene": "free_beam",
            "frequencies": [15],
            "base": {"amplitude_mm": 2.0},
            "grid": {"twist_deg": [0, 90, 180]},
        }
    )
    df = pd.DataFrame(
        {"twist_deg": [0.0, 90.0, 180.0], "tip_major_mm": [1.0, 2, 3], "tip_minor_mm": [0.1, 0.2, 0.3]}
        | {"tip_tilt_deg": [0.0, 5, 10]}
    )
    titles: list[str] = []
    original = Figure.savefig

    def spy(self, *args, **kwargs):
        titles.append(self.get_suptitle())
        return original(self, *args, **kwargs)

    Figure.savefig = spy  # type: ignore[method-assign]
    try:
        plot_sweep(df, spec, tmp_path / "twist.png")
    finally:
        Figure.savefig = original  # type: ignore[method-assign]
    assert titles == ["twist_sweep: tip path ellipse vs twist angle φ at 15 Hz, A = 2 mm (free_beam)"]


def test_ellipse_and_trajectory_titles_say_which_point_they_show(contact, tmp_path):
    from beambench.analysis.figures import FIGURES
    from beambench.analysis.figures.ellipse import ellipse_figure
    from beambench.analysis.figures.registry import ReportOptions

    fig = ellipse_figure([contact])
    assert fig is not None and fig.get_suptitle().startswith("Tip path")
    assert "foot" in fig.get_suptitle()  # and that the trajectory grid shows another point
    from matplotlib.figure import Figure

    titles: list[str] = []
    original = Figure.savefig

    def spy(self, *args, **kwargs):
        titles.append(self.get_suptitle())
        return original(self, *args, **kwargs)

    Figure.savefig = spy  # type: ignore[method-assign]
    try:
        FIGURES["trajectories"].draw([contact], tmp_path / "t.png", ReportOptions())
    finally:
        Figure.savefig = original  # type: ignore[method-assign]
    assert titles and titles[0].startswith("Foot paths (the beam's contact end, not the tip)")


def test_force_window_shows_contacts_spaced_as_the_regime_label_says():
    from beambench.analysis.figures.forces import force_window

    f = 32.0
    # a 1/2 step whose first touchdowns are 1.8 and 3.7 cycles apart, then settles into every 2nd cycle
    td = np.array([0.5, 2.3, 6.0, 8.0, 10.0, 12.0, 14.0, 16.0]) / f
    w = force_window(td, f, "1/2", cycles=6.0)
    assert w.typical and w.gaps == pytest.approx([2.0, 2.0])
    assert 5.0 / f <= w.start_s + 0.5 / f <= 10.0 / f  # the window starts at a touchdown of the regular part
    # no window of this step is typical of its label: the title must say so
    odd = np.array([0.5, 2.3, 6.0, 7.1, 11.0, 12.2]) / f
    w = force_window(odd, f, "1/2", cycles=6.0)
    assert not w.typical and w.gaps
    assert force_window(td, f, "irregular", cycles=6.0).start_s == pytest.approx(td[0] - 0.5 / f)


def test_compare_title_fits_its_figure_with_long_session_names(contact):
    import copy

    from beambench.analysis.figures.contact_frequency import contact_frequency_figure

    a, b = copy.copy(contact), copy.copy(contact)
    a.name = "contact_sweep_sim_20261204-122837_seed0_long_name"
    b.name = "contact_sweep_rig_20261204-153012_after_recalibration"
    fig = contact_frequency_figure([a, b])
    assert fig is not None
    fig.canvas.draw()
    box = fig.axes[0].title.get_window_extent()
    assert box.x0 >= 0 and box.x1 <= fig.bbox.x1, (box, fig.bbox)
    assert a.name[:20] in fig.axes[0].get_title().replace("\n", "")


def test_compare_refuses_sessions_of_different_rigs(tmp_path):
    from typer.testing import CliRunner

    from beambench.cli import app

    c = write_synthetic_session(tmp_path / "c.h5", SynthSession([SynthStep(20.0)], record_s=0.5, settle_s=0.2))
    w = write_synthetic_session(
        tmp_path / "w.h5", SynthSession([SynthStep(20.0)], rig="walker", record_s=0.5, settle_s=0.2)
    )
    before = {p: p.stat().st_mtime_ns for p in (c, w)}
    res = CliRunner().invoke(app, ["compare", str(c), str(w), "-o", str(tmp_path / "r"), "-q"])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and "contact session" in lines[0] and "walker session" in lines[0]
    assert "Traceback" not in res.output
    assert not (tmp_path / "r").exists() and {p: p.stat().st_mtime_ns for p in (c, w)} == before


def test_fit_figure_legend_sits_below_the_traces_in_the_report_style(tmp_path):
    from matplotlib.figure import Figure

    from beambench.studies.fit import release as fit
    from beambench.studies.fit.figure import plot_fit

    t = np.linspace(0, 0.1, 40)
    m = np.random.default_rng(0).random((40, 3, 3)) * 1e-3
    r = fit.FitResult(
        "prb3", {}, fit.default_base("prb3"), 1, 1, 1, 0, 1, 1, 1, 1, True, "", t, m, m, ("tip1", "tip2", "tip3")
    )
    seen: list[Figure] = []
    original = Figure.savefig

    def spy(self, *args, **kwargs):
        seen.append(self)
        return original(self, *args, **kwargs)

    Figure.savefig = spy  # type: ignore[method-assign]
    try:
        plot_fit([r], tmp_path / "fit.png")
    finally:
        Figure.savefig = original  # type: ignore[method-assign]
    fig = seen[0]
    assert all(ax.get_legend() is None for ax in fig.axes)  # no legend over tip2's trace after the release
    assert len(fig.legends) == 1
    fig.canvas.draw()
    legend_top = fig.legends[0].get_window_extent().y1
    assert all(legend_top <= ax.get_window_extent().y0 for ax in fig.axes)  # below every panel
    assert not fig.axes[0].spines["top"].get_visible()  # the report's style (common.figures.STYLE)
