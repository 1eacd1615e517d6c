"""The synthetic-session helper's own truth: touchdown direction holds whatever crank turn a step starts at."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.analysis.session_analysis import analyze_session
from beambench.analysis.synthetic import (
    SynthSession,
    SynthStep,
    _crank_turns,
    _schedule,
    markers,
    write_synthetic_session,
)
from beambench.sinks.session_file.reader import read_session


def _foot_velocity_at_touchdowns(cfg: SynthSession) -> list[float]:
    """Median foot x velocity (raw marker array, noise off) at each step's touchdowns, by hand."""
    sched = _schedule(cfg)
    t = np.arange(0.0, sched[-1][2], 1e-4)
    pos = markers(cfg, t, np.random.default_rng(0))
    vx = np.gradient(pos[:, 2, 0], t)
    turns = _crank_turns(cfg, sched, t)
    out = []
    for i, st in enumerate(cfg.steps):
        start_turns = _crank_turns(cfg, sched, np.array([sched[i][0]]))[0]
        local = turns - start_turns
        sel = (t >= sched[i][1]) & (t < sched[i][2])
        # touchdowns at local phase 0 of every k-th cycle: the samples right after each integer local turn
        td = sel & (np.diff(np.floor(local), prepend=np.floor(local[0])) > 0)
        td &= np.floor(local) % st.contact_every == 0
        out.append(float(np.median(vx[np.flatnonzero(td)])))
    return out


@pytest.mark.parametrize("first_hz", [4.0, 5.0, 7.3])
def test_touchdown_direction_truth_at_non_integer_start_turns(first_hz, tmp_path):
    # the second step starts at 10 turns (4 Hz), 12.5 (5 Hz) or 18.25 (7.3 Hz); the third at 37.5, 40 or 45.75
    steps = [
        SynthStep(first_hz, 1, touchdown_velocity_sign=1),
        SynthStep(11.0, 1, touchdown_velocity_sign=-1),
        SynthStep(13.0, 2, touchdown_velocity_sign=1),
    ]
    cfg = SynthSession(steps, mocap_noise_m=0.0, seed=3)
    raw = _foot_velocity_at_touchdowns(cfg)
    assert [int(np.sign(v)) for v in raw] == [1, -1, 1]
    a = analyze_session(read_session(write_synthetic_session(tmp_path / "s.h5", cfg)))
    assert a.table["touchdown_direction"].tolist() == [1, -1, 1]
