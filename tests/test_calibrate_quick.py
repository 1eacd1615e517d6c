"""``beambench calibrate sim --quick`` on the contact rig plans its budget around its verify stage: the whole search,
the verify stage's written-protocol maps included, ends within the budget. The toy rig of test_calibrate_verdict
(its map's transitions known functions of two unknowns) with a cost: each map takes wall time in proportion to
the time it simulates (the twin's cost: steps × (settle + record) at its timestep), and a verify stage whose
written protocol is a long sweep, as the contact rig's is."""

from __future__ import annotations

import json
from dataclasses import replace

from beambench.sim.settings import SimSettings
from beambench.studies.twin_calibration import RIGS, CalibrationBase
from beambench.studies.twin_calibration.contact import CONTACT_QUICK
from conftest import pause
from test_calibrate_verdict import TOY, TOY_FREQS, TOY_UNKNOWNS, _beambench, _threads, toy_simulate

WALL_PER_SIM_S = 0.0075  # wall seconds per simulated second: a search map ~0.8 s, a written-protocol map ~3.6 s
WRITTEN = SimSettings(settle_s=2.0, record_s=5.0)  # the written protocol's windows (the shipped sweep's)


def costly_simulate(
    base: CalibrationBase, values: dict[str, float], frequencies: list[float], sim: SimSettings
) -> dict:
    """The toy map after as long as the twin would take to simulate it (a model of compute time, not a wait)."""
    pause(WALL_PER_SIM_S * len(frequencies) * (sim.settle_s + sim.record_s), "the twin's compute time for these maps")
    return toy_simulate(base, values, frequencies, sim)


def test_a_quick_contact_search_ends_within_its_budget_with_its_verify_stage(monkeypatch, tmp_path):
    """The coarse stage stops before a batch whose end would leave less than the verify stage's expected time (two
    written-protocol maps, one round of the two workers): the command's search, verify and seed spread included,
    ends within --budget-s, and it still searched (lines from the prior) before verifying its best point.
    Budgets that stop *starting* stages at shares of the budget ended ~1.5 budgets later here."""
    rig = replace(
        TOY,
        simulate=costly_simulate,
        verify=lambda base: (TOY_FREQS, WRITTEN),
        quick=CONTACT_QUICK,
        cpu_per_sim_s=lambda base, sim: WALL_PER_SIM_S,  # the budget's model of a map's time is the map's time
    )
    monkeypatch.setattr("beambench.studies.executor.make_executor", _threads)
    t = tmp_path / "t.yaml"
    t.write_text("rig: contact\ncontinuous_below_hz: 17\nhalf_at_hz: 32\nthird_at_hz: 50\n")
    out = tmp_path / "out"
    budget = 12.0
    with RIGS.stand_in("contact", rig):
        res = _beambench(
            "calibrate", "sim", "--targets", str(t), "--out", str(out), "--quick", "--budget-s", str(budget)
        )
    assert res.returncode in (0, 5), res.stderr  # 5: written, a target missed
    rep = json.loads((out / "t_calibrated_report.json").read_text())
    stages = [h["stage"] for h in rep["history"]]
    assert rep["history"][-1]["elapsed_s"] <= budget, rep["history"]
    # the verify stage was reserved, not squeezed out, and the search ran before it
    assert stages[-1] == "verify", stages
    assert stages.count("prior line") >= 2, json.dumps(rep["history"])


def test_without_a_fine_stage_the_verify_runs_the_best_distinct_coarse_points(tmp_path):
    """With refine_top 0 (contact --quick) the verify stage's candidates are the winner and then the best coarse
    points that are distinct from those already picked (a near-copy of the winner is skipped), not the winner
    alone."""
    from concurrent.futures import ThreadPoolExecutor

    import pandas as pd

    from beambench.studies.executor import Pool
    from beambench.studies.twin_calibration.evaluate import EvalLog, Point, SearchSettings
    from beambench.studies.twin_calibration.rig import parse_targets
    from beambench.studies.twin_calibration.search import Search, verify_candidates

    targets = parse_targets({"rig": "contact", "continuous_below_hz": 17, "half_at_hz": 32}, "t.yaml")
    settings = SearchSettings.quick(refine_top=0, verify_top=3)
    s = Search(TOY, targets, EvalLog(tmp_path / "t.evals.jsonl"), settings)
    with ThreadPoolExecutor(2) as ex:
        s.start(Pool(ex, 2, "threads"))
        js = {0.40: 0.1, 0.4001: 0.15, 0.7: 0.3, 0.1: 0.5, 0.9: 0.9}  # u: J; 0.4001 is a near-copy of the best
        s.ev.points = [Point({"u": u, "w": 1.0}, j, {}, pd.DataFrame(), {}, "coarse", 0) for u, j in js.items()]
        got = [p.values["u"] for p in verify_candidates(s, s.ev.points[0])]
    assert got == [0.40, 0.7, 0.1]


def test_the_reserve_prices_the_later_maps_as_their_batches_are_priced(tmp_path):
    """Search.reserve_s (what the coarse stage leaves to the later stages) prices the fine maps of the best
    refine_top points and the winner's spread seeds with Evaluator.cost_s, as their batches add to the budget's
    clock: each map's overhead and the rig's own stage windows (its stage_sim) included."""
    from concurrent.futures import ThreadPoolExecutor

    import pytest

    from beambench.studies.executor import Pool
    from beambench.studies.twin_calibration.evaluate import EvalLog, SearchSettings, makespan
    from beambench.studies.twin_calibration.rig import parse_targets
    from beambench.studies.twin_calibration.search import Search

    def long_fine(stage: str, sim: SimSettings) -> SimSettings:
        return sim.replace(settle_s=3.0, record_s=4.0) if stage == "fine" else sim

    rig = replace(TOY, stage_sim=long_fine)
    targets = parse_targets({"rig": "contact", "continuous_below_hz": 17, "half_at_hz": 32}, "t.yaml")
    settings = SearchSettings.quick(refine_top=3, spread_seeds=3, plan_finish=True)
    s = Search(rig, targets, EvalLog(tmp_path / "t.evals.jsonl"), settings)
    with ThreadPoolExecutor(2) as ex:
        s.start(Pool(ex, 2, "threads"))
        fine_map = s.ev.cost_s(s.ev.stage_sim("fine"), len(s.fine))
        assert s.ev.stage_sim("fine").settle_s == 3.0  # the rig's own window, not the search's
        assert s.reserve_s(fine=False) == pytest.approx(makespan([fine_map] * 2, 2))  # spread: two more seeds
        fine_batch = makespan([fine_map] * 3, 2)
        assert s.reserve_s(fine=True) - s.reserve_s(fine=False) == pytest.approx(fine_batch)


def test_an_unknown_the_short_search_never_moved_is_reported_not_pinned():
    """A quick search may end after its first line (one unknown moved): the intervals still pin the moved unknown
    from its maps' landmarks and report the unmoved one over its whole box, not pinned (the report had no
    intervals at all for such a search)."""
    import pandas as pd

    from beambench.studies.twin_calibration.contact_objective import contact_checks
    from beambench.studies.twin_calibration.evaluate import Point
    from beambench.studies.twin_calibration.intervals import intervals
    from beambench.studies.twin_calibration.rig import parse_targets

    targets = parse_targets({"rig": "contact", "continuous_below_hz": 17, "half_at_hz": 32}, "t.yaml")
    u, w = TOY_UNKNOWNS

    def point(x: float) -> Point:
        values = {"u": x, "w": 1.0}
        steps = pd.DataFrame(toy_simulate(CalibrationBase("toy", "none"), values, TOY_FREQS, SimSettings())["steps"])
        return Point(values, abs(x - 0.4), {}, steps, {}, "coarse", 0)

    points = [point(x) for x in (0.1, 0.2, 0.3, 0.35, 0.4, 0.45, 0.5, 0.6)]
    winner = points[4]
    got = intervals(contact_checks(targets), winner, points, [u, w])
    assert got, "no intervals"
    assert got["unknowns"]["w"] == {"lo": w.lo, "hi": w.hi, "pinned": False}
    iu = got["unknowns"]["u"]
    assert iu["pinned"] and iu["lo"] < 0.4 < iu["hi"] and iu["hi"] - iu["lo"] < 0.5, iu
    assert iu["given"] == ["w"]  # u's interval holds w where the search left it
    assert "w not moved by the search" in got["method"]
