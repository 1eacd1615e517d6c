"""Parameter sweeps: plans from YAML, resumable Parquet tables, physics of the swept metrics, CLI errors."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from beambench.cli import app
from beambench.studies.executor import batch_size, chunks
from beambench.studies.sweep.run import (
    SweepError,
    SweepSpec,
    load_sweep,
    plan,
    read_table,
    run_local,
    run_sweep,
    write_table,
)
from conftest import cli, descendants, one_line_error, process_alive, wait_until

ROOT = Path(__file__).resolve().parents[1]

SMALL = SweepSpec.model_validate(
    {
        "name": "small",
        "scene": "free_beam",
        "base": {"model": "prb3", "twist_deg": 90},
        "grid": {"chirality": [1, -1], "k": [0.34, 0.5]},
        "frequencies": [15, 30],
        "settle_s": 0.3,
        "record_s": 0.2,
    }
)


def test_shipped_sweep_files_plan_the_papers_studies():
    twist = load_sweep(ROOT / "protocols" / "twist_sweep.yaml")
    jobs = plan(twist)
    assert [j.point["twist_deg"] for j in jobs] == list(np.arange(0, 181, 5.0))  # φ = 0…180° step 5°
    assert {j.frequency_hz for j in jobs} == {15.0} and twist.axes() == ["twist_deg"]
    pair = load_sweep(ROOT / "protocols" / "chirality_sweep.yaml")
    jobs = plan(pair)
    assert {j.point["chirality"] * j.point["twist_deg"] for j in jobs} == {90.0, -90.0}
    assert len({j.id for j in jobs}) == len(jobs) == 18


def test_sweep_resumes_and_skips_finished_points(tmp_path):
    out = tmp_path / "small.parquet"
    first = run_sweep(SMALL, out, workers=2)
    assert first.computed == 8 and first.skipped == 0 and first.table["ok"].all()
    again = run_sweep(SMALL, out, workers=2)
    assert again.computed == 0 and again.tasks == 0
    pd.testing.assert_frame_equal(first.table, again.table, check_exact=True)
    # an interrupted sweep: drop some finished rows, rerun computes exactly those, the table comes back equal
    cut = first.table.drop(index=[1, 4, 6]).reset_index(drop=True)
    write_table(cut, out, SMALL)
    resumed = run_sweep(SMALL, out, workers=1, batch_size=2)
    assert resumed.computed == 3
    pd.testing.assert_frame_equal(first.table, resumed.table, check_exact=True)
    # the same points computed in this process, in other batches, give the same numbers
    pd.testing.assert_frame_equal(first.table, run_local(SMALL), check_exact=True)


def test_chirality_mirrors_the_tip_ellipse():
    """φ → −φ mirrors the path across the beam's plane of symmetry: same axes, tilt negated, sense reversed."""
    t = run_local(SMALL)
    for k in (0.34, 0.5):
        for f in (15, 30):
            pos = t[(t.chirality == 1) & (t.k == k) & (t.frequency_hz == f)].iloc[0]
            neg = t[(t.chirality == -1) & (t.k == k) & (t.frequency_hz == f)].iloc[0]
            assert neg.tip_major_mm == pytest.approx(pos.tip_major_mm, rel=1e-6)
            assert neg.tip_minor_mm == pytest.approx(pos.tip_minor_mm, rel=1e-4)
            assert neg.tip_tilt_deg == pytest.approx(-pos.tip_tilt_deg, abs=1e-4)
            assert {pos.tip_sense, neg.tip_sense} == {"cw", "ccw"}
    # the drive is 2 mm: the lab-frame path's major axis is about the 4 mm stroke, the beam adds to it
    assert (t.tip_major_mm > 3.5).all() and (t.tip_major_mm < 12).all()
    # a stiffer beam (k 0.34 → 0.5) is further below resonance: less relative motion
    soft = t[(t.k == 0.34) & (t.frequency_hz == 30)].tip_rel_major_mm.iloc[0]
    stiff = t[(t.k == 0.5) & (t.frequency_hz == 30)].tip_rel_major_mm.iloc[0]
    assert stiff < soft


def test_untwisted_beam_moves_in_a_line():
    spec = SMALL.model_copy(update={"grid": {"twist_deg": [0.0, 45.0]}, "base": {}, "frequencies": [20]})
    t = run_local(spec)
    flat, twisted = t.iloc[0], t.iloc[1]
    assert flat.tip_minor_mm < 1e-6 and twisted.tip_minor_mm > 1e-3  # the twist couples the two planes


def test_contact_points_report_contacts_per_cycle(tmp_path):
    spec = SweepSpec.model_validate(
        {
            "name": "c",
            "scene": "contact",
            "grid": {"gap_mm": [1.0, 5.5]},
            "frequencies": [40],
            "settle_s": 0.4,
            "record_s": 0.4,
        }
    )
    t = run_local(spec)
    near, far = t.iloc[0], t.iloc[1]
    assert near.contacts_per_cycle == pytest.approx(0.5, abs=0.1) and near.regime == "1/2"  # planning facts
    assert far.n_contacts == 0 and far.regime == "none"  # 5.5 mm: the PRB3 foot never touches (planning facts)


def test_bad_sweep_files_fail_with_one_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: b\nscene: free_beam\ngrid: {twist: [0, 90]}\n")
    with pytest.raises(SweepError, match=r"bad\.yaml: grid.*'twist' is not a scene parameter"):
        load_sweep(bad)
    res = CliRunner().invoke(app, ["sweep", str(bad)])
    assert res.exit_code == 2 and "twist" in res.output and "Traceback" not in res.output
    bad.write_text("name: b\nbase: {model: rod10, k: 0.3}\n")
    with pytest.raises(SweepError, match="k/b set the PRB3 joints"):
        load_sweep(bad)
    ok = tmp_path / "ok.yaml"
    ok.write_text("name: ok\nfrequencies: [5]\nsettle_s: 0.1\nrecord_s: 0.1\n")
    res = CliRunner().invoke(app, ["sweep", str(ok), "--out", str(tmp_path / "t.csv")])
    assert res.exit_code == 2 and ".parquet" in res.output
    res = CliRunner().invoke(app, ["sweep", str(ok), "--workers", "-1"])
    assert res.exit_code == 2
    (tmp_path / "junk.parquet").write_text("not parquet")
    with pytest.raises(SweepError, match="not a readable sweep table"):
        read_table(tmp_path / "junk.parquet")


def test_an_unknown_parameter_set_is_one_line_before_any_worker_starts(tmp_path):
    """A point whose ``params`` names no set of its model's family is refused when the file is read (it reached
    the workers as a ParamsError traceback, exit 1, after the pool had started)."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("scene: free_beam\ngrid: {params: [paper, nosuch]}\nfrequencies: [15]\n")
    with pytest.raises(SweepError, match=r"bad\.yaml: params = 'nosuch': no parameter set prb3_nosuch\.yaml"):
        load_sweep(bad)
    code, out = cli("sweep", str(bad), "--out", str(tmp_path / "t.parquet"), "--workers", "1")
    one_line_error(code, out, "bad.yaml", "params = 'nosuch'")
    assert not (tmp_path / "t.parquet").exists()


def test_options_the_scene_does_not_build_are_refused(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("name: s\nscene: free_beam\ngrid: {gap_mm: [1, 5]}\n")
    with pytest.raises(SweepError, match=r"s.yaml: .*gap_mm applies to scene: contact only"):
        load_sweep(f)
    f.write_text("name: s\nscene: contact\ngrid: {gap_mm: [1, 5]}\n")
    assert len(load_sweep(f).scene_points()) == 2
    f.write_text("name: s\nbase: {model: beam7}\n")
    with pytest.raises(SweepError, match=r"s.yaml: .*model = 'beam7': unknown beam model"):
        load_sweep(f)


def test_sweep_command_writes_table_and_figure(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text(
        "name: s\nscene: free_beam\ngrid: {twist_deg: [0, 90, 180]}\nfrequencies: [15]\nsettle_s: 0.3\nrecord_s: 0.2\n"
    )
    out = tmp_path / "s.parquet"
    res = CliRunner().invoke(app, ["sweep", str(f), "--out", str(out), "--workers", "1"])
    assert res.exit_code == 0, res.output
    assert "3 computed" in res.output and out.exists() and out.with_suffix(".png").exists()
    res = CliRunner().invoke(app, ["sweep", str(f), "--out", str(out), "--workers", "1"])
    assert res.exit_code == 0 and "0 computed, 3 already done" in res.output
    assert "s: all 3 points done before, nothing to compute" in res.stderr and " on nothing" not in res.stderr


def test_batch_sizes_balance_and_bound_tasks():
    assert batch_size(500, 2) == 32 and batch_size(37, 2) == 10 and batch_size(8, 2) == 4
    assert batch_size(10_000, 64) == 20 and batch_size(100_000, 64) == 50
    assert [len(c) for c in chunks(list(range(23)), 10)] == [10, 10, 3]


def test_killed_sweep_resumes_from_task_files(tmp_path):
    """A sweep killed mid-run leaves finished tasks in <table>.parts/: the rerun merges them, computes the rest."""
    import subprocess
    import sys

    spec_file = tmp_path / "k.yaml"
    spec_file.write_text(
        "name: k\nscene: free_beam\ngrid: {twist_deg: [0, 30, 60, 90, 120, 150]}\n"
        "frequencies: [10, 20]\nsettle_s: 0.5\nrecord_s: 0.5\nbatch_size: 1\n"
    )
    out = tmp_path / "k.parquet"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "beambench.cli",
            "sweep",
            str(spec_file),
            "--out",
            str(out),
            "--workers",
            "1",
            "--no-figure",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    parts = tmp_path / "k.parquet.parts"
    wait_until(lambda: len(list(parts.glob("*.parquet"))) >= 3, 60, "three points saved", 0.05)
    children = descendants(proc.pid)
    assert len(children) >= 2  # at least the worker and the process it was started from
    proc.kill()
    proc.wait()
    # the sweep's worker processes die with it, mid-task (no orphans left computing or waiting)
    try:
        wait_until(lambda: not any(process_alive(c) for c in children), 10, "the sweep's workers to end", 0.05)
    finally:
        for c in children:  # do not leave them behind even when the assertion fails
            if process_alive(c):
                os.kill(c, signal.SIGKILL)
    saved = len(list(parts.glob("*.parquet")))
    assert 3 <= saved < 12  # killed part-way
    spec = load_sweep(spec_file)
    resumed = run_sweep(spec, out, workers=1)
    assert resumed.skipped >= saved and resumed.computed == 12 - resumed.skipped
    assert not parts.exists() and len(resumed.table) == 12 and list(resumed.table["point"]) == list(range(12))
    pd.testing.assert_frame_equal(resumed.table, run_local(spec), check_exact=True)


def test_integrator_and_model_axes_batch_separately():
    """Points that cannot share a batch (other integrator, other model) still land in one task correctly."""
    spec = SweepSpec.model_validate(
        {
            "name": "i",
            "scene": "free_beam",
            "grid": {"integrator": ["implicitfast", "euler", "rk4"]},
            "base": {"timestep": 2e-5},
            "frequencies": [20],
            "settle_s": 0.3,
            "record_s": 0.2,
        }
    )
    t = run_local(spec)
    assert t["ok"].all()
    # converged integrators agree on the ellipse (rk4 needs its own stage drive: a wrong one would be far off)
    assert np.ptp(t.tip_major_mm) < 0.01 * t.tip_major_mm.mean()
    assert np.ptp(t.tip_rel_major_mm) < 0.02 * t.tip_rel_major_mm.mean()


FIGURES = """
import sys
import matplotlib
matplotlib.use("svg")  # a user's own choice (a notebook's inline backend, say) must survive
import numpy as np, pandas as pd
from beambench.studies.fit import figure as fit_figure, release as fit
from beambench.studies.sweep import figure as sweep_figure, run as sweep
from beambench.studies.ladder import figures as ladder_figures
out = sys.argv[1]
spec = sweep.SweepSpec.model_validate({"grid": {"twist_deg": [0, 90]}, "frequencies": [10, 15]})
df = pd.DataFrame({"twist_deg": [0, 0, 90, 90], "frequency_hz": [10, 15, 10, 15], "tip_major_mm": [1, 2, 3, 4],
                   "tip_minor_mm": [1, 1, 1, 1], "tip_tilt_deg": [3, 4, 5, 6]})
sweep_figure.plot_sweep(df, spec, f"{out}/sweep.png")
t, m = np.linspace(0, 0.1, 20), np.random.default_rng(0).random((20, 3, 3))
r = fit.FitResult("prb3", {}, fit.default_base("prb3"), 1, 1, 1, 0, 1, 1, 1, 1, True, "", t, m, m, ("a", "b", "c"))
fit_figure.plot_fit([r], f"{out}/fit.png")
table = pd.DataFrame({"model": ["prb3", "rod10"], "integrator": ["implicitfast", "euler"], "timestep": [1e-4, 1e-4],
                      "frequency_hz": [5, 5], "status": ["ok", "diverged"]})
ladder_figures.plot_stability_map(table, f"{out}/map.png")
print(matplotlib.get_backend(), "matplotlib.pyplot" in sys.modules)
"""


def test_figures_leave_the_users_matplotlib_backend_alone(tmp_path):
    import subprocess
    import sys

    res = subprocess.run(
        [sys.executable, "-c", FIGURES, str(tmp_path)], capture_output=True, text=True, timeout=300, check=True
    )
    assert res.stdout.split() == ["svg", "False"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit.png", "map.png", "sweep.png"]
    assert all(p.stat().st_size > 10_000 for p in tmp_path.iterdir())
