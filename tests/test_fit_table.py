"""``beambench fit``'s table: the truth and error columns only where the session's twin is the fitted model (a
sim session made by it), filled there; a session of another model (the release test's PRB3 fitted as a rod) or a
measured one has no empty columns, and the caption says why."""

from __future__ import annotations

import io
from types import SimpleNamespace

import numpy as np
from rich.console import Console

from beambench.commands.fit import _print_results


def _result(model: str, truth: dict) -> SimpleNamespace:
    return SimpleNamespace(
        model=model,
        truth=truth,
        values={"k": 0.33, "b": 0.0035},
        intervals={},
        confidence=0.95,
        rms_mm=0.5,
        mae_mm=0.4,
        method="sysid",
        nfev=40,
        generations=5,
        wall_s=1.0,
        at_bounds={},
    )


def _table(results: list) -> str:
    out = io.StringIO()
    data = SimpleNamespace(t=np.zeros(10), names=("tip1", "tip2"))
    _print_results(results, data, Console(file=out, width=250))
    return out.getvalue()


def test_a_sim_session_of_the_fitted_model_fills_truth_and_error():
    text = _table([_result("prb3", {"model": "prb3", "k": 0.30, "b": 0.0035})])
    assert "truth" in text and "error" in text.split("fitted")[1]
    assert "+10.00 %" in text and "+0.00 %" in text  # k 0.33 against 0.30; b exact


def test_a_session_of_another_model_has_no_empty_truth_columns():
    text = _table([_result("rod5", {"model": "prb3", "k": 0.30})])
    header = next(line for line in text.splitlines() if "parameter" in line)
    assert "truth" not in header and "error" not in header, header
    assert "this session's twin is prb3, not the fitted model" in " ".join(text.split())
    measured = _table([_result("prb3", {})])
    assert "truth" not in next(line for line in measured.splitlines() if "parameter" in line)
    assert "no truth column: a measured session" in " ".join(measured.split())
