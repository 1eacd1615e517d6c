"""Sweep direction, repeats and reference steps: protocol fields, the plan, /steps columns, spread and hysteresis."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from beambench.acquisition.protocol.plan import plan
from beambench.acquisition.protocol.schema import parse_protocol
from beambench.analysis.branches import annotate_branches
from beambench.analysis.session_analysis import analyze_session
from beambench.analysis.synthetic import SynthSession, SynthStep, write_synthetic_session
from beambench.common.yaml_config import ConfigError
from beambench.sinks.session_file.reader import read_session


def _plan(text: str) -> list[tuple[float, str, str, int]]:
    return [(s.frequency_hz, s.direction, s.kind, s.repeat) for s in plan(parse_protocol(text))]


def test_direction_repeats_and_reference_order():
    assert [f for f, *_ in _plan("sweep: {start: 1, stop: 3, step: 1}\n")] == [1, 2, 3]  # default: up
    assert _plan("sweep: {start: 1, stop: 3, step: 1, direction: down}\n") == [
        (3, "down", "sweep", 0),
        (2, "down", "sweep", 0),
        (1, "down", "sweep", 0),
    ]
    both = _plan("sweep: {frequencies: [1, 2, 3], direction: both}\n")
    assert [(f, d) for f, d, *_ in both] == [(1, "up"), (2, "up"), (3, "up"), (2, "down"), (1, "down")]
    inter = _plan("sweep: {frequencies: [1, 2], repeats: 2}\n")
    assert [(f, r) for f, _, _, r in inter] == [(1, 0), (2, 0), (1, 1), (2, 1)]  # default: interleaved
    blocks = _plan("sweep: {frequencies: [1, 2], repeats: 2, repeat_order: blocks}\n")
    assert [(f, r) for f, _, _, r in blocks] == [(1, 0), (1, 1), (2, 0), (2, 1)]
    ref = _plan("sweep: {frequencies: [1, 2, 3, 4, 5]}\nreference: {frequency_hz: 9, every_steps: 2}\n")
    assert [f for f, *_ in ref] == [9, 1, 2, 9, 3, 4, 9, 5, 9]  # first, every 2 sweep steps, last
    assert [k for _, _, k, _ in ref].count("reference") == 4
    p = parse_protocol(
        "sweep: {frequencies: [1, 2, 3], direction: both, repeats: 2}\nreference: {frequency_hz: 9, every_steps: 4}\n"
    )
    assert p.n_planned_steps() == len(plan(p)) == 14


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("sweep: {frequencies: [1], direction: sideways}\n", "sweep.direction"),
        ("sweep: {frequencies: [1], repeats: 0}\n", "sweep.repeats"),
        ("sweep: {frequencies: [1], repeat_order: random}\n", "sweep.repeat_order"),
        ("sweep: {frequencies: [1]}\nreference: {frequency_hz: 0, every_steps: 2}\n", "reference.frequency_hz"),
        ("sweep: {frequencies: [1]}\nreference: {frequency_hz: 5, every_steps: 1.5}\n", "reference.every_steps"),
        ("sweep: {frequencies: [1]}\nreference: {frequency_hz: 5}\n", "reference.every_steps"),
    ],
)
def test_bad_fields_are_named(text, field):
    with pytest.raises(ConfigError) as err:
        parse_protocol(text)
    assert field in str(err.value) and "\n" not in str(err.value)


def test_reference_frequency_is_limited():
    p = parse_protocol("sweep: {frequencies: [1]}\nreference: {frequency_hz: 60, every_steps: 2}\n")
    assert p.limit_violations()[0][1] == 60


# an up/down sweep, twice, interleaved: 20 Hz touches every cycle going up, every other cycle coming down
def _step(f: float, k: int, d: str, r: int) -> SynthStep:
    return SynthStep(f, k, direction=d, repeat=r)


BRANCHES = [("up", 10.0, 1), ("up", 20.0, 1), ("up", 30.0, 1), ("down", 20.0, 2), ("down", 10.0, 1)]


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    steps = [_step(f, k, d, r) for r in range(2) for d, f, k in BRANCHES]
    cfg = SynthSession(steps, settle_s=0.3, record_s=1.0, seed=5)
    path = write_synthetic_session(tmp_path_factory.mktemp("b") / "both.h5", cfg)
    return analyze_session(read_session(path))


def test_steps_record_direction_and_repeat(swept):
    t = swept.table
    assert t["direction"].tolist() == [d for _ in range(2) for d, _, _ in BRANCHES]
    assert t["repeat"].tolist() == [0] * 5 + [1] * 5
    assert set(t["kind"]) == {"sweep"}


def test_hysteresis_flagged_where_the_branches_differ(swept):
    t = swept.table
    flagged = t.groupby("frequency_hz")["hysteresis"].all()
    assert flagged.to_dict() == {10.0: False, 20.0: True, 30.0: False}
    at20 = t[t["frequency_hz"] == 20.0].iloc[0]
    assert at20["hysteresis_delta"] == pytest.approx(-0.5, abs=0.06)
    assert "regime 1 up, 1/2 down" in at20["hysteresis_why"]
    # noise: one touchdown in ~20 cycles, repeats identical
    assert 0 < at20["contacts_per_cycle_noise"] < 0.1


def test_repeats_give_a_spread_and_interval(swept):
    t = swept.table
    row = t[(t["frequency_hz"] == 10.0) & (t["direction"] == "up")].iloc[0]
    assert row["contacts_per_cycle_mean"] == pytest.approx(1.0, abs=0.11)  # 10 cycles a window: ±1 touchdown
    assert row["contacts_per_cycle_ci95_lo"] <= row["contacts_per_cycle_mean"] <= row["contacts_per_cycle_ci95_hi"]
    assert np.isfinite(row["tip_major_mm_std"])


def test_spread_by_hand():
    t = pd.DataFrame(
        {
            "frequency_hz": [5.0, 5.0, 5.0, 6.0],
            "direction": ["up"] * 4,
            "kind": ["sweep"] * 4,
            "record_s": [2.0] * 4,
            "contacts_per_cycle": [0.9, 1.0, 1.1, 0.5],
            "regime": ["1", "1", "1", "1/2"],
        }
    )
    a = annotate_branches(t)
    assert a["contacts_per_cycle_std"].iloc[0] == pytest.approx(0.1)
    half = 4.302653 * 0.1 / np.sqrt(3)  # t(0.975, 2)
    assert a["contacts_per_cycle_ci95_hi"].iloc[0] == pytest.approx(1.0 + half, rel=1e-5)
    assert np.isnan(a["contacts_per_cycle_std"].iloc[3])  # a group of one has no spread
    assert a["contacts_per_cycle_noise"].iloc[0] == pytest.approx(np.sqrt(0.1**2 + 0.01 / 3))
    assert "hysteresis" not in a  # one direction only


def test_old_sessions_read_as_up(tmp_path):
    """A /steps table without the new columns (as written before them) analyses as up, sweep, repeat 0."""
    import h5py

    path = write_synthetic_session(tmp_path / "old.h5", SynthSession([SynthStep(10.0, 1)], settle_s=0.3, record_s=1.0))
    with h5py.File(path, "a") as f:
        old = f["steps"][()][["index", "frequency_hz", "t_start_ns", "t_settled_ns", "t_end_ns", "status"]]
        del f["steps"]
        f.create_dataset("steps", data=np.array(old.tolist(), dtype=old.dtype), maxshape=(None,))
    t = analyze_session(read_session(path)).table
    assert (t["direction"].iloc[0], t["kind"].iloc[0], t["repeat"].iloc[0]) == ("up", "sweep", 0)


def test_synthetic_tip_ellipse_has_no_crossing(swept):
    t = swept.table
    assert (t["tip_crossings"] == 0).all()
    assert set(t["tip_loop_sense"]) == {"cw"}  # SynthStep's default: clockwise
    assert not t["tip_path_inverts"].any()
