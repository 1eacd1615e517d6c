"""Per-period path shape on paths with a known number of self-crossings and sense."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from beambench.analysis.path_shape import annotate_inversions, loop_sense, self_crossings, shape_columns

F = 10.0
T = np.arange(0.0, 1.0, 1 / 360.0)
W = 2 * np.pi * F * T


def _ellipse(cw: bool) -> np.ndarray:
    return np.column_stack([1.5 * np.cos(W), (-1 if cw else 1) * 0.5 * np.sin(W)])


def _lemniscate() -> np.ndarray:  # Gerono's figure-8: x = cos, y = sin·cos, one crossing at the origin
    return np.column_stack([np.cos(W), 0.6 * np.sin(W) * np.cos(W)])


def test_ellipse_has_no_crossing_and_its_sense():
    noisy = _ellipse(True) + np.random.default_rng(0).normal(0, 0.02, (len(T), 2))
    c = shape_columns({"foot": noisy, "tip": _ellipse(False)}, T, F, "1")
    assert c == {"foot_crossings": 0, "foot_loop_sense": "cw", "tip_crossings": 0, "tip_loop_sense": "ccw"}


def test_lemniscate_has_one_crossing_and_mixed_sense():
    noisy = _lemniscate() + np.random.default_rng(1).normal(0, 0.01, (len(T), 2))
    c = shape_columns({"foot": noisy}, T, F, "1")
    assert c["foot_crossings"] == 1
    assert c["foot_loop_sense"] == "mixed"


def test_period_of_a_half_regime_keeps_the_two_cycle_shape():
    # a path that repeats every two drive cycles: a figure-8 in a 1/2 regime, over one cycle it would not close
    w2 = W / 2
    xy = np.column_stack([np.cos(w2), 0.6 * np.sin(w2) * np.cos(w2)])
    assert shape_columns({"foot": xy}, T, F, "1/2")["foot_crossings"] == 1


@pytest.mark.parametrize("n_loops", [2, 3])
def test_rose_crossings(n_loops):
    # a limaçon-like loop-in-loop: r = 0.5 + cos(θ) has one self-crossing; a polyline by hand with two
    th = np.linspace(0, 2 * np.pi, 400)
    if n_loops == 2:
        r = 0.5 + np.cos(th)
        loop = np.column_stack([r * np.cos(th), r * np.sin(th)])
        assert self_crossings(loop) == 1
    else:
        star = np.array([[np.cos(a), np.sin(a)] for a in np.deg2rad([90, 234, 18, 162, 306, 90])])
        assert self_crossings(star) == 5  # a pentagram crosses itself five times
    assert loop_sense(np.column_stack([np.cos(th), np.sin(th)])) == "ccw"


def test_inversion_between_neighbouring_steps():
    t = pd.DataFrame(
        {
            "frequency_hz": [5.0, 6.0, 7.0, 8.0, 7.0],
            "direction": ["up", "up", "up", "up", "down"],
            "kind": ["sweep"] * 5,
            "repeat": [0] * 5,
            "foot_loop_sense": ["cw", "cw", "ccw", "mixed", "cw"],
        }
    )
    assert annotate_inversions(t)["foot_path_inverts"].tolist() == [False, False, True, False, False]
