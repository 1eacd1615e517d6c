"""Why RK4 diverges on the beam models: explicit RK4 against the models' stiffest mode (an overdamped joint on a
light link). The predicted largest stable timestep brackets where the simulation really diverges, and every
failed row of a ladder or sweep says why."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.sim.engine.stability import modes, rk4_amplification, rk4_max_timestep, unstable_reason
from beambench.sim.models.registry import beam_model
from beambench.sim.scenes.free_beam import build_free_beam_spec, equilibrium_qpos, frequency_sweep
from beambench.sim.settings import SimSettings


def _model(name: str, integrator: str, h: float):
    m = build_free_beam_spec(beam_model(name, "paper"), 90, integrator, h).compile()
    return m, equilibrium_qpos(m)


def test_rk4_region_on_the_real_axis():
    assert rk4_amplification(np.array([-2.78]))[0] < 1 < rk4_amplification(np.array([-2.80]))[0]
    assert rk4_max_timestep(np.array([-1000.0])) == pytest.approx(2.7853e-3, rel=1e-3)


def test_the_predicted_rk4_limit_brackets_the_real_divergence():
    m, q = _model("prb3", "rk4", 1e-4)
    lam = modes(m, q)
    h_max = rk4_max_timestep(lam)
    worst = lam[np.argmax(np.abs(lam))]
    assert abs(worst.imag) < 1e-6 * abs(worst) and worst.real < -1e4  # the overdamped joint: real, fast
    assert 1e-5 < h_max < 5e-5  # below the quick ladder's smallest step (5e-5): rk4 diverges there, a fact
    ran = {}
    for h in (0.85 * h_max, 1.15 * h_max):
        s = SimSettings(settle_s=0.05, record_s=0.02, twist_deg=90, amplitude_m=0.002, integrator="rk4", timestep=h)
        ran[h] = bool(frequency_sweep(beam_model("prb3", "paper"), (25,), s).ok[0])
    assert list(ran.values()) == [True, False], ran


def test_a_diverged_rk4_run_is_explained():
    m, q = _model("prb3", "rk4", 5e-5)
    why = unstable_reason(m, "rk4", q)
    assert "explicit RK4 is unstable at dt 5e-05 s" in why and "needs dt ≤ 3.2e-05 s" in why
    assert "joint damping" in why


def test_a_one_point_rk4_sweep_stores_the_reason():
    from beambench.studies.sweep.run import SweepSpec, run_local

    spec = SweepSpec.model_validate(
        {
            "name": "r",
            "scene": "free_beam",
            "base": {"integrator": "rk4", "timestep": 5e-5},
            "frequencies": [20],
            "settle_s": 0.05,
            "record_s": 0.05,
        }
    )
    t = run_local(spec)
    assert not t["ok"].iloc[0]
    assert "explicit RK4 is unstable" in str(t["reason"].iloc[0])


def test_the_quick_speed_accuracy_chart_says_what_it_measured(tmp_path):
    """The quick chart: says "quick" and its settings, has the shipped twins' model, shows inaccurate front
    points hollow, and marks the paper's times as another CPU's."""
    import pandas as pd
    from matplotlib.figure import Figure

    from beambench.studies.ladder.figures import ladder_note, plot_speed_accuracy
    from beambench.studies.ladder.run import QUICK, TWIN_MODEL, summarize

    assert TWIN_MODEL == "rod5g" and TWIN_MODEL in QUICK.models
    rows = []
    for model, (wall, err, status) in {"prb3": (0.01, 2.0, "ok"), TWIN_MODEL: (0.1, 0.5, "inaccurate")}.items():
        for f in QUICK.frequencies:
            rows.append(
                dict(model=model, integrator="implicitfast", timestep=1e-3, frequency_hz=f, status=status)
                | dict(tip_err_mm=err, wall_s_per_10s=wall, cpu_s_per_10s=wall, is_reference=False, label="quick")
            )
    summary = summarize(pd.DataFrame(rows))
    figs: list[Figure] = []
    original = Figure.savefig

    def spy(self, *args, **kwargs):
        figs.append(self)
        return original(self, *args, **kwargs)

    Figure.savefig = spy  # type: ignore[method-assign]
    try:
        plot_speed_accuracy(summary, tmp_path / "sa.png", note=ladder_note(QUICK))
    finally:
        Figure.savefig = original  # type: ignore[method-assign]
    ax = figs[0].axes[0]
    assert "QUICK ladder: 5/25/45 Hz, 0.4 s settle" in ax.get_title() and "scaled to 10 s" in ax.get_title()
    texts = [t.get_text() for t in ax.texts]
    assert sum("another CPU" in t for t in texts) == 2
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(t.startswith(TWIN_MODEL) and "twins" in t for t in legend)
    faces = {}
    for c in ax.collections:
        off = c.get_offsets()
        if len(off) == 1:
            faces[round(float(off[0][0]), 3)] = c.get_facecolors()
    assert len(faces[0.1]) == 0 or faces[0.1][0][3] == 0  # the inaccurate twin point: hollow
    assert faces[0.01][0][3] > 0  # the accurate one: filled
