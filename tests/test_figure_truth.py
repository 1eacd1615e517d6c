"""Figures whose titles match what one sees: the force traces mark each counted touchdown and each dip the contact
detection merged, inside the trace; the trajectory grid draws the mocap noise a path's vertical motion must clear;
the ellipse's tilt panel says why none of its points is certain; the contact-frequency figure draws the paper's
regimes and counts the steps that agree. Each test checks the data the figure is drawn from."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure

from beambench.acquisition.forces.contact_events import ContactParams, force_contacts
from beambench.analysis.session_analysis import SessionAnalysis, StepResult, analyze_session
from beambench.analysis.synthetic import SynthSession, SynthStep, write_synthetic_session
from beambench.analysis.trajectory import mean_path
from beambench.sinks.session_file.reader import read_session

# ------------------------------------------------------------------------------------------------- forces


def _chattering_step(f: float, k: int, dip_s: float, flight_s: float) -> StepResult:
    """A step on the plate except for a flight every k-th cycle (a touchdown after it) and a short dip to zero
    once in every other cycle, at a known phase: 1 kHz force, 4 s."""
    t = np.arange(0.0, 4.0, 1e-3)
    ph = (t * f) % 1.0
    cyc = np.floor(t * f)
    flight = (cyc % k == 0) & (ph >= 0.40) & (ph < 0.40 + flight_s * f)
    dip = (cyc % k != 0) & (ph >= 0.50) & (ph < 0.50 + dip_s * f)
    normal = 0.15 + 0.1 * np.sin(2 * np.pi * ph)
    normal[flight | dip] = 0.0
    force = np.stack([normal, 0.05 * np.cos(2 * np.pi * ph)], 1)
    c, s = force_contacts(t, normal, f)
    row = {"regime": s.regime, "contacts_per_cycle": s.contacts_per_cycle, "analysis_frequency_hz": f}
    return StepResult(0, f, row, t_force=t, force=force, contacts=c)


@pytest.mark.parametrize(("f", "k"), [(22.0, 3), (30.0, 2)])
def test_force_panel_marks_each_touchdown_and_each_merged_dip_inside_the_trace(f, k):
    from beambench.analysis.figures.forces import _column, force_panel

    r = _chattering_step(f, k, dip_s=0.03 / f, flight_s=0.3 / f)  # dips 3 %, flights 30 % of a period
    assert r.row["regime"] == f"1/{k}"  # the dips do not count: the detection merges them
    cycles = 6.0
    p = force_panel(r, cycles)
    assert len(p.touchdowns_ms) == cycles / k  # one per k cycles, as the title's regime says
    assert len(p.merged_dips_ms) == cycles - cycles / k  # every other cycle dips once
    limit = ContactParams().min_flight_fraction * 1e3 / f
    assert p.min_flight_ms == pytest.approx(limit)
    assert all(b - a < limit for a, b in p.merged_dips_ms)
    # contacts shaded only where the trace is
    assert p.contacts_ms and all(p.t_ms[0] <= a < b <= p.t_ms[-1] for a, b in p.contacts_ms)
    fig = Figure()
    ax_n, ax_t = fig.subplots(2)
    title, drawn = _column(ax_n, ax_t, r, "s", None, cycles)
    assert (drawn.touchdowns_ms, drawn.merged_dips_ms) == (p.touchdowns_ms, p.merged_dips_ms)  # what it drew
    assert f"{int(cycles / k)} ▼ touchdowns, {int(cycles - cycles / k)} ◇ dips < {limit:.1f} ms merged" in title


# --------------------------------------------------------------------------------------------- sessions


def _savefig_spy(monkeypatch: pytest.MonkeyPatch) -> list[Figure]:
    drawn: list[Figure] = []
    original = Figure.savefig

    def spy(self, *args, **kwargs):
        drawn.append(self)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", spy)
    return drawn


@pytest.fixture(scope="module")
def noisy(tmp_path_factory) -> SessionAnalysis:
    """A foot on the plate throughout (no vertical motion) and one lifting 0.3 mm each cycle, 0.1 mm mocap noise."""
    d = tmp_path_factory.mktemp("noisy")
    steps = [SynthStep(6.0, -1), SynthStep(9.0, -1), SynthStep(12.0, 0)]
    cfg = SynthSession(steps, record_s=1.5, settle_s=0.3, mocap_noise_m=1e-4, lift_mm=0.3, seed=5)
    return analyze_session(read_session(write_synthetic_session(d / "noisy.h5", cfg)))


def test_trajectory_bands_hold_a_still_foot_and_not_a_lifting_one(noisy, tmp_path, monkeypatch):
    from beambench.analysis.figures.style import step_frequency
    from beambench.analysis.figures.trajectories import _contact_period_cycles, fig_trajectories, noise_bands

    noise = float(noisy.table["path_noise_mm"].iloc[0])
    # the session's own estimate of the mocap noise of a path: the foot's and the stage's 0.1 mm, relative
    assert noise == pytest.approx(0.1 * np.sqrt(2), rel=0.15)
    heights = {}
    for r in noisy.steps:
        mp = mean_path(r.t_mocap, r.paths["foot"], _contact_period_cycles(r) / step_frequency(r))
        raw, floor = noise_bands(r, "foot", len(mp))
        assert raw == pytest.approx(2 * noise) and 0 < floor < raw
        y = mp[:, 1] - np.mean(mp[:-1, 1])
        heights[r.frequency_hz] = (float(np.max(np.abs(y))), floor)
        if r.frequency_hz < 12:  # the still foot: its raw trace inside the raw band, its mean path inside the floor
            xy = r.paths["foot"]
            dev = np.abs(xy[:, 1] - np.nanmean(xy[:, 1]))
            assert np.mean(dev[np.isfinite(dev)] <= raw) > 0.9
            assert heights[r.frequency_hz][0] <= floor
    lift, floor = heights[12.0]
    assert lift > 2 * floor  # 0.15 mm of lift clears the floor: the band does not hide real motion
    drawn = _savefig_spy(monkeypatch)
    assert fig_trajectories([noisy], tmp_path / "t.png") is not None
    ax = drawn[-1].axes[0]
    spans = sorted(round(p.get_extents().height, 6) for p in ax.patches)
    assert len(spans) >= 2  # both bands are drawn behind the paths
    labels = [t.get_text() for leg in drawn[-1].legends for t in leg.get_texts()]
    assert any("mocap noise per frame" in s and f"{noise:.2f}" in s for s in labels), labels


def test_force_traces_of_continuous_contact_keep_their_panels(noisy, tmp_path, monkeypatch):
    """Steps without a touchdown draw no touchdown marks (an empty unclipped line collapsed the layout)."""
    from beambench.analysis.figures.forces import choose_force_frequencies, fig_forces

    drawn = _savefig_spy(monkeypatch)
    frequencies = choose_force_frequencies([noisy])
    assert frequencies == [9.0]  # the continuous regime's middle step: the only regime with contact
    assert fig_forces([noisy], tmp_path / "f.png", frequencies) is not None
    fig = drawn[-1]
    assert all(ax.get_position().height > 0.2 for ax in fig.axes)  # each of the two rows keeps its height
    assert "no touchdown here" in fig.axes[0].get_title()
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "touchdown (counted)" not in labels and "contact" in labels


def test_the_ellipse_panel_says_why_no_sense_is_certain(noisy, tmp_path, monkeypatch):
    from beambench.analysis.figures.ellipse import ellipse_figure, why_uncertain

    t = pd.DataFrame(
        {
            "tip_ellipse_r2": [0.05, 0.2, 0.31],
            "tip_major_mm": [0.1, 0.2, 0.3],
            "path_noise_mm": [0.14] * 3,
        }
    )
    why = why_uncertain(t, "tip")
    assert "R² 0.05–0.31" in why and "0.10–0.30 mm" in why and "0.56 mm" in why
    assert why_uncertain(t.assign(tip_ellipse_r2=[0.05, 0.6, 0.2]), "tip") == ""  # one certain step: no excuse
    # the synthetic tip's ellipse (3 × 1 mm) is well above 0.1 mm of noise: certain, no note drawn
    fig = ellipse_figure([noisy])
    assert fig is not None and not fig.axes[1].texts
    # the same session with the tip's fits made poor: the panel says why
    poor = SessionAnalysis(**{**noisy.__dict__, "table": noisy.table.assign(tip_ellipse_r2=0.1)})
    fig = ellipse_figure([poor])
    assert fig is not None
    assert [x.get_text() for x in fig.axes[1].texts] and "No step's tilt or sense" in fig.axes[1].texts[0].get_text()


# ------------------------------------------------------------------------------------- contact frequency


def test_paper_regimes_are_the_papers_and_the_agreement_counts_misses():
    from beambench.analysis.figures.contact_frequency import PAPER_REGIMES, paper_agreement, paper_regime

    assert [paper_regime(f) for f in (5, 17, 18, 25, 26, 37, 38, 44, 45)] == [
        "continuous",
        "continuous",
        "1",
        "1",
        "1/2",
        "1/2",
        "1/3",
        "1/3",
        "",
    ]
    f = np.arange(1.0, 46.0)
    as_paper = pd.DataFrame({"frequency_hz": f, "regime": [paper_regime(x) or "1" for x in f]})
    assert paper_agreement(as_paper) == (44, 44)  # 45 Hz is past the paper's range
    twin = as_paper.assign(regime=np.where((f >= 22) & (f <= 24), "1/2", as_paper["regime"]))
    assert paper_agreement(twin) == (41, 44)  # ½ early at 22–24 Hz: three misses
    assert PAPER_REGIMES[-1].to_hz == 44


def test_contact_frequency_figure_draws_the_papers_bands_and_says_the_agreement(noisy):
    from beambench.analysis.figures.contact_frequency import contact_frequency_figure, paper_agreement

    fig = contact_frequency_figure([noisy])
    assert fig is not None
    ax = fig.axes[0]
    bands = [ln for ln in ax.lines if ln.get_linewidth() >= 8]
    assert len(bands) >= 1  # the session reaches 12 Hz: the paper's continuous band below 18 Hz
    assert [list(ln.get_xdata()) for ln in bands] == [pytest.approx([0.0, 12.0 * 1.05])]  # to the axis end
    n, m = paper_agreement(noisy.table)
    assert (n, m) == (2, 3)  # continuous at 6 and 9 Hz as the paper; no contact at 12 Hz is a miss
    assert f"the paper's regime at {n} of {m} steps" in ax.get_title().replace("\n", " ")
