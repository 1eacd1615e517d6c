"""``beambench calibrate sim``: targets, bad input (one line, exit 2), the objective's shape, a tiny calibration
that recovers a known gap, resuming from the evaluation log, and the runnable protocol it writes."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pytest

from beambench.sim.scenes.contact_regimes import transitions
from beambench.sim.settings import SimSettings
from beambench.studies.twin_calibration import (
    RIGS,
    CalibrationBase,
    Interrupted,
    SearchSettings,
    calibrate,
    get_rig,
    write_report,
)
from beambench.studies.twin_calibration.contact import simulate_contact
from beambench.studies.twin_calibration.contact_objective import contact_objective, regime_level
from beambench.studies.twin_calibration.rig import load_targets, parse_targets
from beambench.studies.twin_calibration.targets import CalibrationInputError, Targets

REPO = Path(__file__).resolve().parents[1]
PAPER = REPO / "calibration" / "paper_contact_targets.yaml"


def _beambench(*args: str) -> subprocess.CompletedProcess:
    """The CLI in-process (typer's runner: separate stdout/stderr, the exit code), as a CompletedProcess."""
    from typer.testing import CliRunner

    from beambench.cli import app

    r = CliRunner().invoke(app, list(args))
    if r.exception is not None and not isinstance(r.exception, SystemExit):
        raise r.exception
    return subprocess.CompletedProcess(list(args), r.exit_code, r.stdout, r.stderr)


def _one_line_exit_2(res: subprocess.CompletedProcess, words: str) -> None:
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("beambench: error: ") and words in lines[0], res.stderr
    assert "Traceback" not in res.stderr


# ------------------------------------------------------------------------------------------------ targets


def test_paper_targets_parse_into_a_step_map():
    t = load_targets(PAPER)
    assert t.rig == "contact"
    assert t.scalars["continuous_below_hz"] == 18 and t.scalars["half_at_hz"] == 26 and t.scalars["third_at_hz"] == 38
    assert t.scalars["tangential_sign"] == {26.0: -1.0, 40.0: 1.0}
    lab = dict(zip(t.table["frequency_hz"], t.table["regime"]))
    assert lab[1.0] == lab[17.0] == "continuous"
    assert lab[18.0] == lab[25.0] == "1"
    assert lab[26.0] == lab[37.0] == "1/2"
    assert lab[38.0] == lab[42.0] == "1/3"
    assert 43.0 not in lab  # nothing is said above ⅓ + 4 Hz
    # the map's own transitions are the targets
    assert transitions(t.table["frequency_hz"].to_numpy(), list(t.table["regime"])) == {
        "continuous_below_hz": 18.0,
        "half_at_hz": 26.0,
        "third_at_hz": 38.0,
    }


def test_walker_targets_parse():
    t = load_targets(REPO / "calibration" / "paper_walker_targets.yaml")
    assert t.rig == "walker" and t.scalars["speed_mm_s"] == {23.0: -35.7, 65.0: 156.3}


@pytest.mark.parametrize(
    "data, words",
    [
        ({"rig": "contact", "half_at_hz": 40, "third_at_hz": 30}, "half_at_hz = 40 is not below third_at_hz = 30"),
        ({"rig": "contact", "continuous_below_hz": 30, "half_at_hz": 26}, "continuous_below_hz = 30 is above"),
        ({"rig": "contact"}, "needs at least one of"),
        ({"rig": "contact", "half_at_hz": "soon"}, "half_at_hz = 'soon'"),
        ({"rig": "contact", "half_at_hz": 26, "tangential_sign": {26: 2}}, "expected -1 or 1"),
        ({"rig": "contact", "half_at_hz": 26, "halfway": 3}, "halfway: unknown field"),
        ({"rig": "treadmill", "half_at_hz": 26}, "unknown rig"),
    ],
)
def test_contradicting_or_malformed_targets_are_refused(data, words):
    with pytest.raises(CalibrationInputError, match=words.replace("(", r"\(")):
        parse_targets(data, "t.yaml")


def test_cli_bad_input_is_one_line_and_exit_2(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("rig: contact\ncontinuous_below_hz: 18\nhalf_at_hz: 40\nthird_at_hz: 30\n")
    _one_line_exit_2(_beambench("calibrate", "sim", "--targets", str(bad), "--out", str(tmp_path)), "not below")
    _one_line_exit_2(
        _beambench("calibrate", "sim", "--targets", str(tmp_path / "none.yaml"), "--out", str(tmp_path)),
        "no such targets file",
    )
    _one_line_exit_2(
        _beambench("calibrate", "sim", str(tmp_path / "none.h5"), "--out", str(tmp_path)), "no such session file"
    )
    _one_line_exit_2(_beambench("calibrate", "sim", "--out", str(tmp_path)), "give a SESSION file or --targets")
    _one_line_exit_2(
        _beambench("calibrate", "sim", "--targets", str(PAPER), "--free", "k_scale,gravity", "--out", str(tmp_path)),
        "rig unknowns are",
    )
    assert not any(tmp_path.glob("*calibrated*"))


def test_opt_in_unknowns_reach_the_scene_and_stay_out_of_the_default_search():
    """frame_mass_g / mass_dx_mm are the contact rig's opt-in unknowns: not fitted unless named, neutral (0) when
    not, and a fitted value lands in the parameter set's rig block (SI) — the scene the map is computed on."""
    from dataclasses import replace

    from beambench.studies.twin_calibration.contact import calibrated_params

    rig = get_rig("contact")
    assert rig.default_free == ("b_scale", "preload_mm", "friction_scale")
    names = {u.name: u for u in rig.unknowns}
    assert names["frame_mass_g"].default == 0.0 and names["mass_dx_mm"].default == 0.0
    base = CalibrationBase("prb3", "contact_paper")
    p = calibrated_params(base, {"k_scale": 1.0, "frame_mass_g": 4.0, "mass_dx_mm": 12.0})
    assert p.rig["frame_mass"] == pytest.approx(0.004) and p.rig["mass_dx"] == pytest.approx(0.012)
    assert p.rig["friction"] == 1.5  # the prior's rig block is kept
    plain = calibrated_params(base, {"k_scale": 1.0})
    assert "frame_mass" not in plain.rig and "mass_dx" not in plain.rig
    # not fitted, the prior's own value stays (the shipped default's frame mass is 10 g)
    stuck = replace(base, params="contact_stuck")
    assert calibrated_params(stuck, {"k_scale": 1.0}).rig["frame_mass"] == pytest.approx(0.010)
    assert names["frame_mass_g"].opt_in and names["mass_dx_mm"].opt_in and names["mass_dy_mm"].opt_in
    # the search's fixed values leave the opt-in unknowns out unless they are fixed explicitly
    from beambench.studies.twin_calibration.search import fixed_values

    free = [names[n] for n in rig.default_free]
    assert fixed_values(names, free, SearchSettings()) == {"k_scale": 1.0}  # k stays the prior's
    assert fixed_values(names, free, SearchSettings(fixed={"frame_mass_g": 2.0})) == {
        "k_scale": 1.0,
        "frame_mass_g": 2.0,
    }
    assert fixed_values(names, free[:2], SearchSettings()) == {"k_scale": 1.0, "friction_scale": 1.0}
    # the search's first line starts at the prior set's own values
    from beambench.studies.twin_calibration.contact import contact_prior

    assert contact_prior(stuck) == pytest.approx(
        {
            "k_scale": 1.0,
            "b_scale": 1.0,
            "friction_scale": 1.0,
            "frame_mass_g": 10.0,
            "mass_dx_mm": 0.0,
            "mass_dy_mm": 0.0,
        }
    )
    # the friction is scaled from the prior's own (the stuck sole's 6, the scene's default 0.5 for the paper set)
    assert calibrated_params(stuck, {"friction_scale": 0.9}).rig["friction"] == pytest.approx(5.4)
    assert calibrated_params(replace(base, params="paper"), {"friction_scale": 0.9}).rig["friction"] == pytest.approx(
        0.45
    )
    assert calibrated_params(stuck, {"friction_scale": 0.9}).rig["frame_mass"] == pytest.approx(0.010)


def test_a_rig_the_calibrator_does_not_know_is_refused(tmp_path):
    """Contact and walker are registered; a release-test rig has nothing to calibrate against a sweep."""
    assert get_rig("walker").name == "walker" and {"contact", "walker"} <= set(RIGS)
    t = tmp_path / "release.yaml"
    t.write_text("rig: release\nspeed_mm_s: {23: -35.7}\n")
    _one_line_exit_2(_beambench("calibrate", "sim", "--targets", str(t), "--out", str(tmp_path)), "release")


@pytest.fixture(scope="module")
def twin_session(tmp_path_factory) -> Path:
    """A short twin-made contact session (3 steps)."""
    d = tmp_path_factory.mktemp("session")
    proto = d / "short.yaml"
    proto.write_text(
        "name: short\nrig: contact\nbackend: sim\nsweep: {frequencies: [20, 28, 36]}\nsettle_s: 0.3\nrecord_s: 0.6\n"
        "sim: {model: prb3, params: paper, plate_gap_mm: 1.08, noise: true, seed: 2}\n"
    )
    res = _beambench("run", str(proto), "--out", str(d), "--name", "short", "--rerun", "off")
    assert res.returncode == 0, res.stderr
    return Path(res.stdout.strip().splitlines()[-1])


def test_session_without_contact_data_is_refused(twin_session, tmp_path):
    copy = tmp_path / "no_force.h5"
    copy.write_bytes(twin_session.read_bytes())
    with h5py.File(copy, "r+") as f:
        del f["acquisition/loadcell"]
    _one_line_exit_2(_beambench("calibrate", "sim", str(copy), "--out", str(tmp_path)), "no load-cell data")


# ------------------------------------------------------------------------------------------------ objective


def test_regime_levels_are_ordered_as_the_map_runs():
    seq = ["continuous", "2", "1", "1/2", "1/3", "none"]
    levels = [regime_level(s) for s in seq]
    assert levels == sorted(levels) and len(set(levels)) == len(levels)
    # an irregular step sits between its neighbours; a mostly-on-plate stepper leans toward continuous
    assert regime_level("1", 1.0) < regime_level("irregular", 0.6) < regime_level("1/2", 0.5)
    assert regime_level("1", 1.0, 0.95) == regime_level("continuous") < regime_level("1", 1.0, 0.85) < 0.0


FREQS = [float(f) for f in range(20, 46, 2)]
FAST = SimSettings(settle_s=0.6, record_s=1.0, integrator="implicitfast")
BASE = CalibrationBase("prb3", "paper")
TRUE_PRELOAD = 0.05  # mm: the paper set sags ~1.13 mm; gap ≈ 1.08 mm (½ and ⅓ inside 20–44 Hz)


@pytest.fixture(scope="module")
def truth() -> tuple[Targets, dict]:
    out = simulate_contact(BASE, {"preload_mm": TRUE_PRELOAD}, FREQS, FAST)
    steps = pd.DataFrame(out["steps"])
    cols = ["frequency_hz", "regime", "contacts_per_cycle", "in_contact_fraction"]
    # the session's protocol: the sweep and windows the truth ran with (what the verify stage re-runs)
    proto = (
        "name: truth\nrig: contact\nbackend: sim\nsweep: {start: 20, stop: 44, step: 2}\nsettle_s: 0.6\n"
        "record_s: 1.0\nsim: {model: prb3, params: paper, noise: false}\n"
    )
    targets = Targets("contact", "twin", steps[cols], protocol_text=proto, prior={"params": BASE.params})
    return targets, out["extras"]


def test_objective_is_zero_at_the_truth_and_grows_away_from_it(truth):
    targets, _ = truth
    js = {}
    for p in (-0.15, -0.05, TRUE_PRELOAD, 0.15, 0.3):  # one run each
        steps = pd.DataFrame(simulate_contact(BASE, {"preload_mm": p}, FREQS, FAST)["steps"])
        js[p] = contact_objective(steps, targets)[0]
    assert js[TRUE_PRELOAD] == 0.0
    assert js[-0.15] >= js[-0.05] > 0.0  # monotone on each side of the truth
    assert js[0.3] >= js[0.15] > 0.0


def _steps(regimes: dict[tuple[int, int], str]) -> pd.DataFrame:
    freqs, labels = [], []
    for (lo, hi), lab in regimes.items():
        for f in range(lo, hi + 1):
            freqs.append(float(f))
            labels.append(lab)
    return pd.DataFrame({"frequency_hz": freqs, "regime": labels})


def test_transitions_are_scored_beyond_the_per_step_levels():
    """A map that lacks the target's ⅓ band, or has a stray low ½ step, is a missed calibration (the goal is
    each transition within ± 2 Hz) although it differs from the target at only a few steps: the transition term
    makes it cost as much as a whole band of wrong steps."""
    from beambench.studies.twin_calibration.contact_objective import TRANSITION_WEIGHT, transition_misfit

    targets = parse_targets({"rig": "contact", "continuous_below_hz": 15, "half_at_hz": 30, "third_at_hz": 42})
    exact = _steps({(1, 14): "continuous", (15, 29): "1", (30, 41): "1/2", (42, 46): "1/3"})
    no_third = _steps({(1, 14): "continuous", (15, 29): "1", (30, 46): "1/2"})
    stray = _steps(
        {(1, 6): "continuous", (7, 7): "1/2", (8, 14): "continuous", (15, 29): "1", (30, 41): "1/2", (42, 46): "1/3"}
    )
    close = _steps({(1, 15): "continuous", (16, 29): "1", (30, 42): "1/2", (43, 46): "1/3"})  # within ± 2 Hz
    j = {
        k: contact_objective(v, targets)
        for k, v in (("exact", exact), ("no_third", no_third), ("stray", stray), ("close", close))
    }
    assert j["exact"][0] == 0.0 and j["exact"][1]["transitions"] == 0.0
    # the missing ⅓ counts as if at the map's top + 2 Hz (48: 6 Hz high → ρ(1.5) = 2), one of three transitions
    assert j["no_third"][1]["transitions"] == pytest.approx(2 / 3)
    assert j["no_third"][0] == pytest.approx(j["no_third"][1]["regime"] + TRANSITION_WEIGHT * 2 / 3)
    # the stray ½ at 7 Hz cuts the continuous edge to 7 (8 Hz low: ρ(2) = 3) and puts the lowest ½ 23 Hz low
    assert transition_misfit(stray, targets) == pytest.approx((3 + (2 * 23 / 4 - 1)) / 3)
    # within the tolerance: (1/4)² for each of two transitions 1 Hz off
    assert j["close"][1]["transitions"] == pytest.approx(2 / 16 / 3)
    assert j["close"][0] < j["no_third"][0] < j["stray"][0]
    # far misses keep their order (a search still sees which is nearer)
    edge_at = {e: _steps({(1, e - 1): "continuous", (e, 29): "1", (30, 41): "1/2", (42, 46): "1/3"}) for e in (7, 10)}
    assert transition_misfit(edge_at[10], targets) < transition_misfit(edge_at[7], targets)
    # a session's scalars without a transition add nothing
    bare = Targets("contact", "x", targets.table, {"half_at_hz": None})
    assert transition_misfit(no_third, bare) == 0.0


def test_the_calibrators_map_is_the_stepped_runs_map(tmp_path):
    """The calibrator fits maps of a stepped sweep; they must be what `beambench run` + `beambench analyze` of the
    same protocol give (maps of every frequency from rest put the continuous edge several Hz lower than the run:
    calibrations fitted on them missed their targets once run)."""
    from beambench.analysis.session_analysis import analyze_session
    from beambench.sim.scenes.contact_regimes import ContactTwin, stepped_regime_map
    from beambench.sim.settings import SimSettings
    from beambench.sinks.session_file.reader import read_session

    freqs = [16, 20, 24, 28, 32, 36]
    proto = tmp_path / "stepped.yaml"
    proto.write_text(
        f"name: stepped\nrig: contact\nbackend: sim\nsweep: {{frequencies: {freqs}}}\nsettle_s: 1.0\nrecord_s: 2.0\n"
        "sim: {model: prb3, params: contact_stuck, noise: false}\n"
    )
    res = _beambench("run", str(proto), "--out", str(tmp_path), "--name", "stepped", "--rerun", "off")
    assert res.returncode == 0, res.stderr
    run = analyze_session(read_session(Path(res.stdout.strip().splitlines()[-1]))).table
    twin = stepped_regime_map(
        freqs, SimSettings(settle_s=1.0, record_s=2.0, integrator="implicitfast"), ContactTwin(params="contact_stuck")
    )
    assert list(run["regime"]) == list(twin["regime"]), (list(run["regime"]), list(twin["regime"]))
    assert {"continuous", "1/2"} <= set(twin["regime"])  # a map with edges, not a row of one label
    assert list(run["tangential_sign"].astype(int)) == list(twin["tangential_sign"])
    # the verify stage's map of a written protocol is that run's analysed map, step for step
    from beambench.studies.twin_calibration.written_run import run_written_protocol

    verify = pd.DataFrame(run_written_protocol(proto)["steps"])
    assert list(verify["frequency_hz"]) == list(run["frequency_hz"])
    assert list(verify["regime"]) == list(run["regime"])
    np.testing.assert_allclose(verify["contacts_per_cycle"], run["contacts_per_cycle"], equal_nan=True)


# ------------------------------------------------------------------------------------------------ calibration


@pytest.mark.slow
def test_tiny_calibration_recovers_the_gap_and_resumes_from_its_log(truth, tmp_path):
    targets, extras = truth
    settings = SearchSettings(
        budget_s=240.0,
        coarse_step_hz=4.0,
        coarse_settle_s=0.6,
        coarse_record_s=1.0,
        fine_settle_s=0.6,
        fine_record_s=1.0,
        popsize=6,
        max_generations=1,
        stall_generations=2,
        good_enough=0.0,
        refine_top=1,
        verify_top=1,
        bracket_rounds=2,
        prior_rounds=3,
        line_cycles=1,
        free=("b_scale", "preload_mm"),
        fixed={"k_scale": 1.0},
    )
    with pytest.raises(Interrupted):  # as if killed after 10 evaluations
        calibrate(
            targets, tmp_path, "tiny", workers=2, settings=SearchSettings(**{**settings.__dict__, "max_evals": 10})
        )
    log = tmp_path / "tiny.evals.jsonl"
    assert len(log.read_text().splitlines()) == 10
    with log.open("a") as fh:
        fh.write('{"key": "cut by a kill')  # a half-written last line is skipped
    res = calibrate(targets, tmp_path, "tiny", workers=2, settings=settings)
    write_report(res, targets, tmp_path, "tiny")  # the command writes the report beside the protocol
    assert res.reused >= 10  # the logged points were not run again
    distinct = {line.split('"key": "')[1][:40] for line in log.read_text().splitlines() if line.startswith('{"key": "')}
    assert res.evaluations == len(distinct) - 10
    gap_true = extras["gap_mm"]
    # the map pins the gap to a few 10 µm (about 10 Hz of shift per 0.1 mm here); b trades a little against it
    assert abs(res.extras["gap_mm"] - gap_true) <= 0.05, (res.extras, gap_true, res.values)
    assert res.j <= 0.1
    want = transitions(targets.table["frequency_hz"].to_numpy(), list(targets.table["regime"]))
    got = res.summary
    for k in ("half_at_hz", "third_at_hz"):
        assert want[k] is not None and got[k] is not None and abs(got[k] - want[k]) <= 2.0, (k, want, got)
    # the winner's map is the written protocol's own sweep and windows (the verify stage), not the search's
    assert [h["stage"] for h in res.history][-1] == "verify"
    assert list(res.steps["frequency_hz"]) == FREQS
    # the written protocol loads and runs dry
    assert res.protocol.is_file() and res.protocol.parent == tmp_path
    dry = _beambench("run", str(res.protocol), "--dry-run")
    assert dry.returncode == 0, dry.stderr
    for name in ("tiny_report.md", "tiny_report.json", "tiny_maps.png", "tiny_objective.png", "tiny_params.yaml"):
        assert (tmp_path / name).is_file(), name


def _short_default_twin_session(d: Path, name: str) -> Path:
    """A 3-step session of the shipped default twin: the shipped contact sweep's protocol (its model, parameter
    set, twist, amplitude, noise and seed) with a short sweep and short windows."""
    import yaml

    from beambench.common.resources import shipped_dir

    doc = yaml.safe_load((shipped_dir("protocols") / "contact_sweep.yaml").read_text())
    assert doc["sim"]["model"] == "rod5g"  # the default twin, not a cheaper stand-in
    doc.update(sweep={"frequencies": [14, 26, 38]}, settle_s=0.5, record_s=1.0)
    proto = d / f"{name}_protocol.yaml"
    proto.write_text(yaml.safe_dump(doc, sort_keys=False))
    res = _beambench("run", str(proto), "--out", str(d), "--name", name, "--rerun", "off")
    assert res.returncode == 0, res.stderr
    return Path(res.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_cli_last_stdout_line_is_a_runnable_protocol(tmp_path):
    """The command end to end on the shipped default twin (rod5g). Its input is a short session of that twin, not
    a targets file: a targets file's written protocol is the shipped 1–40 Hz, 2 + 5 s sweep, which the verify
    stage runs twice (about 2 × 280 s of simulated rig time, most of this test's minutes); a session's written
    protocol is the session's own sweep (3 steps here). What a targets file makes of the shipped protocol:
    test_a_targets_files_twin_is_the_shipped_protocol_extended_to_the_targets."""
    session = _short_default_twin_session(tmp_path, "small")
    out = tmp_path / "out"
    # a 4 s search budget: what is checked is the command's outputs and exit code, not how close the fit gets
    res = _beambench("calibrate", "sim", str(session), "--out", str(out), "--quick", "--budget-s", "4")
    # written either way; 0 only when the report's verdict met every target, else 3 with the misses last
    met = json.loads((out / "small_calibrated_report.json").read_text())["verdict"]["all_met"]
    assert res.returncode == (0 if met else 3), res.stderr
    assert (
        res.stderr.strip()
        .splitlines()[-1]
        .startswith("beambench: every target met" if met else "beambench: not within tolerance")
    )
    last = Path(res.stdout.strip().splitlines()[-1])
    assert last == (out / "small_calibrated.yaml").resolve() and last.is_file()
    dry = _beambench("run", str(last), "--dry-run")
    assert dry.returncode == 0, dry.stderr
    text = last.read_text()
    assert "small_calibrated_params.yaml" in text and "plate_gap_mm" in text
    assert math.isfinite(float(np.loadtxt([text.split("plate_gap_mm:")[1].split()[0]])))


def test_a_targets_files_twin_is_the_shipped_protocol_extended_to_the_targets():
    """A targets file has no protocol: the twin, its windows and the written sweep are the shipped contact
    sweep's, the sweep extended to the targets (what the verify stage runs and the written protocol holds)."""
    import yaml

    from beambench.common.resources import shipped_dir
    from beambench.studies.twin_calibration.contact import contact_base

    shipped = yaml.safe_load((shipped_dir("protocols") / "contact_sweep.yaml").read_text())
    base = contact_base(parse_targets({"rig": "contact", "half_at_hz": 30, "third_at_hz": 32}, "small.yaml"))
    assert (base.model, base.params) == (shipped["sim"]["model"], shipped["sim"]["params"]) == ("rod5g", "physical")
    assert (base.sim.settle_s, base.sim.record_s) == (shipped["settle_s"], shipped["record_s"])
    assert (base.sim.noise, base.sim.seed, base.sim.twist_deg) == (True, 0, 90.0)
    assert base.frequencies == tuple(float(f) for f in range(1, 41))  # ⅓ + 4 Hz = 36 Hz: the 1–40 Hz sweep
    wide = contact_base(parse_targets({"rig": "contact", "half_at_hz": 30, "third_at_hz": 42}, "wide.yaml"))
    assert wide.frequencies == tuple(float(f) for f in range(1, 47))  # extended to ⅓ + 4 Hz


def test_the_written_sweep_reaches_the_targets_and_its_limit_starts_from_the_parsers_default():
    from beambench.acquisition.protocol.schema import Limits
    from beambench.studies.twin_calibration.protocol_out import extended_sweep

    targets = parse_targets({"rig": "contact", "half_at_hz": 30, "third_at_hz": 42})
    top = float(max(targets.frequencies))
    assert top > 45  # the target map runs past ⅓
    doc = extended_sweep({"sweep": {"start": 1, "stop": 40, "step": 1}}, targets)
    assert doc["sweep"]["stop"] == math.ceil(top)
    assert doc["limits"]["max_frequency_hz"] == max(Limits().max_frequency_hz, math.ceil(top))
    # a protocol's own higher limit stays; a sweep that already covers the targets is left alone
    doc = extended_sweep({"sweep": {"start": 1, "stop": 40, "step": 1}, "limits": {"max_frequency_hz": 80}}, targets)
    assert doc["limits"]["max_frequency_hz"] == 80
    doc = extended_sweep({"sweep": {"start": 1, "stop": 60, "step": 1}}, targets)
    assert doc == {"sweep": {"start": 1, "stop": 60, "step": 1}}
