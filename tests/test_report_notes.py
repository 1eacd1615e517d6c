"""The report's notes say what its own per-step table says: continuous contact is not "no contact", a sweep whose
steps mix both says which is which, and an interrupted run's report says it is partial and which steps are
missing (synthetic sessions with a known truth, written through the real session writer, read back by analyze)."""

from __future__ import annotations

import re

import pandas as pd
import pytest
from typer.testing import CliRunner

from beambench.analysis.synthetic import SynthSession, SynthStep, write_synthetic_session
from beambench.cli import app

runner = CliRunner()

# contact_every: -1 = on the plate throughout, 0 = never touching, k = a touchdown every k-th cycle
CASES = {
    "all continuous": [SynthStep(f, -1) for f in (2.0, 4.0, 6.0, 8.0)],
    "none": [SynthStep(f, 0) for f in (10.0, 20.0)],
    "continuous and none": [SynthStep(3.0, -1), SynthStep(5.0, -1), SynthStep(30.0, 0)],
    "mixed with touchdowns": [SynthStep(4.0, -1), SynthStep(12.0, 1), SynthStep(30.0, 0)],
}


def _report(tmp_path, name: str, cfg: SynthSession) -> tuple[str, pd.DataFrame]:
    path = write_synthetic_session(tmp_path / f"{name.replace(' ', '_')}.h5", cfg)
    out = tmp_path / f"{name.replace(' ', '_')}_report"
    res = runner.invoke(app, ["analyze", str(path), "--out", str(out), "--no-write", "-q", "--figures", "none"])
    assert res.exit_code == 0, res.output
    return (out / "index.html").read_text(), pd.read_csv(out / "steps.csv", keep_default_na=False)


def _top(html: str) -> str:
    """The notes above the provenance."""
    return html.split("<h2>Provenance")[0]


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    d = tmp_path_factory.mktemp("notes")
    return {
        name: _report(d, name, SynthSession(steps, record_s=1.2, settle_s=0.3, seed=i))
        for i, (name, steps) in enumerate(CASES.items())
    }


@pytest.mark.parametrize("case", list(CASES))
def test_the_contact_note_agrees_with_the_per_step_table(reports, case):
    html, table = reports[case]
    top = _top(html)
    regimes = set(table["regime"].astype(str))
    touchdowns = (table["n_contacts"].astype(float) > 0).any()
    # every statement at the top is checked against steps.csv, whatever the case
    if "No contact anywhere" in top:
        assert regimes == {"none"} and (table["in_contact_fraction"].astype(float) == 0).all()
    if "Continuous contact in every step" in top:
        assert regimes == {"continuous"} and (table["in_contact_fraction"].astype(float) >= 0.95).all()
    if "No touchdown in any step" in top:
        assert not touchdowns
    said = [
        s for s in ("No contact anywhere", "Continuous contact in every step", "No touchdown in any step") if s in top
    ]
    assert len(said) == (0 if touchdowns else 1), said  # a note exactly when no step has a touchdown
    # the truth of each case, so the checks above had something to check
    expected = {
        "all continuous": "Continuous contact in every step",
        "none": "No contact anywhere",
        "continuous and none": "No touchdown in any step",
        "mixed with touchdowns": None,
    }[case]
    assert said == ([expected] if expected else [])


def test_the_continuous_note_names_the_frequencies_and_the_in_contact_fraction(reports):
    top = _top(reports["all continuous"][0])
    assert "(2, 4, 6, 8 Hz)" in top and "in-contact fraction 1.00" in top
    mixed = _top(reports["continuous and none"][0])
    assert "continuous contact at 3, 5 Hz" in mixed and "no contact at 30 Hz" in mixed


def test_an_interrupted_run_says_so_and_names_the_missing_steps(tmp_path):
    steps = [SynthStep(f, 1) for f in (10.0, 12.0, 14.0, 16.0, 18.0)]
    html, table = _report(tmp_path, "cut", SynthSession(steps, record_s=1.2, settle_s=0.3, interrupted_in=2))
    top = _top(html)
    assert "The run ended early: interrupted by user (SIGINT)." in top
    assert "covers 2 of the 5 planned steps" in top
    assert re.search(r"Cut short[^:]*: step 3 \(index 2, 14 Hz\)\.", top), top
    assert "Never run: steps 4 (index 3, 16 Hz), 5 (index 4, 18 Hz)." in top
    assert list(table["status"]) == ["done", "done", "aborted"]  # the table the banner speaks of
    whole, _ = _report(tmp_path, "whole", SynthSession(steps[:2], record_s=1.2, settle_s=0.3))
    assert "planned steps" not in _top(whole) and "interrupted" not in _top(whole)


SHORT_SWEEP = """
name: cut_short
rig: contact
sweep: {start: 2, stop: 8, step: 2}
settle_s: 0.2
record_s: 0.4
sim: {seed: 5}
"""


def test_a_sim_run_stopped_by_sigint_reports_the_steps_it_never_ran(tmp_path):
    """The runner on the twin, stopped as Ctrl-C stops it (the stop signal's SIGINT) half-way through step 2's record
    window: the report built from the session file names the cut step and the one never run."""
    import signal

    from beambench.acquisition.hub import Hub
    from beambench.acquisition.protocol.plan import motor_limits, plan
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.acquisition.runner import Runner, StopSignal
    from beambench.analysis.report_notes import completeness_note, run_completeness
    from beambench.analysis.session_analysis import analyze_session
    from beambench.backends.sim import SimRig
    from beambench.session.slices import sim_slice
    from beambench.sinks.hdf5 import SessionWriter, read_session

    protocol = parse_protocol(SHORT_SWEEP)
    rig = SimRig(sim_slice(protocol))
    rig.open()
    writer = SessionWriter(tmp_path / "s.h5", {"protocol": SHORT_SWEEP, "rig": "contact", "backend": "sim"})
    hub = Hub([writer], critical=(writer,))
    hub.open([s.describe() for s in rig.streams])
    stop = StopSignal()
    waited: dict[int, float] = {}

    def progress(index: int, _f: float, dt: float) -> None:
        waited[index] = waited.get(index, 0.0) + dt
        if index == 2 and waited[index] > 0.2 + 0.2:  # settled, half of the record window
            stop.request(signal.SIGINT)

    runner = Runner(rig, hub, plan(protocol), motor_limits(protocol), poll_s=0.1, stop=stop, on_progress=progress)
    try:
        result = runner.run()
    finally:
        rig.close()
    assert result.status == "interrupted"
    a = analyze_session(read_session(tmp_path / "s.h5"))
    assert a.ending == ("interrupted", "interrupted by user (SIGINT)")
    c = run_completeness(a)
    assert (c.done, c.missing) == ([0, 1], [2, 3])
    note = completeness_note(c) or ""
    assert "The run ended early: interrupted by user (SIGINT)." in note and "2 of the 4 planned steps" in note
    assert "step 3 (index 2, 6 Hz)." in note and "Never run: step 4 (index 3, 8 Hz)." in note


def test_a_killed_run_and_a_faulted_run_say_how_they_ended():
    from beambench.analysis.report_notes import RunCompleteness, completeness_note

    plan = {0: 2.0, 1: 3.0, 2: 4.0}
    killed = completeness_note(RunCompleteness(plan, [0], [1], "", "")) or ""
    assert "no closing event" in killed and "covers 1 of the 3 planned steps" in killed
    assert "step 2 (index 1, 3 Hz)." in killed and "Never run: step 3 (index 2, 4 Hz)." in killed
    fault = completeness_note(RunCompleteness(plan, [0, 1], [], "fault", "device fault: motor overcurrent")) or ""
    assert "ended early: device fault: motor overcurrent." in fault and "Never run: step 3 (index 2, 4 Hz)." in fault
    assert completeness_note(RunCompleteness(plan, [0, 1, 2], [], "stop", "all steps done")) is None
