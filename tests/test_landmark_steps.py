"""The calibrator's landmark steps: the local linear model, the trust-region step, the contact rig's landmarks,
and the loop reaching targets that need a move along no single unknown (a toy rig whose map's transitions are a
known coupled linear function of its unknowns, evaluated through the calibrator's own Evaluator and log)."""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pandas as pd
import pytest

from beambench.studies.executor import Pool
from beambench.studies.twin_calibration import (
    RIGS,
    CalibratableRig,
    CalibrationBase,
    EvalLog,
    Evaluator,
    SearchSettings,
)
from beambench.studies.twin_calibration.contact_objective import contact_landmarks, contact_objective
from beambench.studies.twin_calibration.landmark_steps import LandmarkPlan, fit_local_linear, landmark_steps, solve_step
from beambench.studies.twin_calibration.rig import parse_targets
from beambench.studies.unknowns import Unknown

# ------------------------------------------------------------------------------------------------ the model


def test_a_plane_is_recovered_from_points_around_x0_and_missing_landmarks_are_skipped():
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 1, (40, 3))
    jac = np.array([[10.0, -4.0, 2.0], [3.0, 8.0, -6.0]])
    y = 5.0 + x @ jac.T
    y[::3, 1] = np.nan  # the second landmark is absent from a third of the maps
    x0 = np.array([0.4, 0.5, 0.6])
    m = fit_local_linear(x, y, x0, scale=0.5)
    assert m.fitted.all()
    np.testing.assert_allclose(m.jacobian, jac, atol=1e-9)
    np.testing.assert_allclose(m.value, 5.0 + jac @ x0, atol=1e-9)


def test_a_landmark_seen_along_one_line_only_is_not_fitted():
    t = np.linspace(0, 1, 12)
    x = np.stack([t, 0.5 + 0 * t, 0.5 + 0 * t], axis=1)  # every point on one line: two directions unseen
    y = (3.0 * t)[:, None]
    m = fit_local_linear(x, y, np.array([0.5, 0.5, 0.5]), scale=0.5)
    assert not m.fitted.any()


def test_the_step_solves_the_model_inside_the_region_and_is_the_best_on_its_edge():
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 1, (30, 3))
    jac = np.array([[12.0, 1.0, -3.0], [2.0, 9.0, 4.0], [-1.0, 3.0, 7.0]])
    m = fit_local_linear(x, x @ jac.T, np.zeros(3), scale=2.0)
    target = np.array([1.0, -0.5, 2.0])
    s = solve_step(m, target, radius=10.0)
    np.testing.assert_allclose(jac @ s, target, atol=1e-8)  # reachable: solved exactly
    r = 0.05
    s = solve_step(m, target, radius=r)
    assert abs(np.linalg.norm(s) - r) < 1e-6
    # no direction on the region's edge does better than the step (2,000 random directions)
    d = rng.normal(size=(2000, 3))
    d = r * d / np.linalg.norm(d, axis=1, keepdims=True)
    best = np.linalg.norm(d @ jac.T - target, axis=1).min()
    assert np.linalg.norm(jac @ s - target) <= best + 1e-9


def test_the_contact_landmarks_skip_a_lone_stray_label():
    targets = parse_targets({"rig": "contact", "continuous_below_hz": 15, "half_at_hz": 30, "third_at_hz": 42})
    freqs = np.arange(10.0, 47.0)
    labels = [
        "continuous" if f < 17 else "1/2" if f == 17 else "1" if f < 28 else "1/2" if f < 40 else "1/3" for f in freqs
    ]
    got = contact_landmarks(pd.DataFrame({"frequency_hz": freqs, "regime": labels}), targets)
    assert got == {"continuous_below_hz": (17.0, 15.0), "half_at_hz": (28.0, 30.0), "third_at_hz": (40.0, 42.0)}
    # a target that names only ½ asks only for ½; a map without ⅓ has none
    only_half = parse_targets({"rig": "contact", "half_at_hz": 30})
    got = contact_landmarks(pd.DataFrame({"frequency_hz": freqs[:25], "regime": labels[:25]}), only_half)
    assert got == {"half_at_hz": (28.0, 30.0)}


# ------------------------------------------------------------------------------------------------ the loop

TOY_FREQS = [float(f) for f in range(3, 50)]
TOY_BASE = CalibrationBase("toy", "none")
TOY_UNKNOWNS = (Unknown("u", 0.0, 1.0), Unknown("v", 0.0, 1.0), Unknown("w", 0.5, 2.0, log=True))


def toy_edges(values: dict[str, float]) -> tuple[float, float, float]:
    """Continuous edge, ½ and ⅓ as a coupled linear function of the unknowns (w on a log axis)."""
    u, v, lw = values["u"], values["v"], math.log10(values["w"])
    return 10.0 + 14 * u + 10 * v - 20 * lw, 22.0 + 16 * u - 6 * v + 10 * lw, 34.0 + 10 * u + 12 * v + 25 * lw


def toy_simulate(base: CalibrationBase, values: dict[str, float], frequencies: list[float], sim: object) -> dict:
    c, h, t = toy_edges(values)
    steps = []
    for f in frequencies:
        reg = "continuous" if f < c else "1" if f < h else "1/2" if f < t else "1/3"
        steps.append({"frequency_hz": f, "regime": reg})
    return {"steps": steps, "extras": {}}


@pytest.fixture
def toy_rig():
    rig = CalibratableRig(
        name="toy-landmarks",
        unknowns=TOY_UNKNOWNS,
        simulate=toy_simulate,
        objective=contact_objective,
        base=lambda t: TOY_BASE,
        write=lambda *a: None,
        summary=lambda s: {},
        landmarks=contact_landmarks,
    )
    with RIGS.stand_in(rig.name, rig):
        yield rig


@pytest.mark.parametrize("want", [(15.0, 30.0, 42.0), (20.0, 27.0, 45.0), (25.0, 33.0, 42.0)])
def test_the_steps_reach_transitions_no_single_unknown_reaches(toy_rig, tmp_path, want):
    targets = parse_targets(
        {"rig": "contact", "continuous_below_hz": want[0], "half_at_hz": want[1], "third_at_hz": want[2]}
    )
    # the truth exists inside the box (the toy map is linear: solve it) …
    a = np.array([[14.0, 10.0, -20.0], [16.0, -6.0, 10.0], [10.0, 12.0, 25.0]])
    truth = np.linalg.solve(a, np.array(want) - [10.0, 22.0, 34.0])
    assert 0 <= truth[0] <= 1 and 0 <= truth[1] <= 1 and -0.3 <= truth[2] <= 0.3
    with ThreadPoolExecutor(2) as ex:
        ev = Evaluator(
            Pool(ex, 2, "threads"), toy_rig, TOY_BASE, targets, EvalLog(tmp_path / "e.jsonl"), SearchSettings()
        )
        # … a start and the points of three lines through it (what the calibrator's prior lines leave) …
        start = {"u": 0.5, "v": 0.5, "w": 1.0}
        design = [start] + [
            {**start, k: val} for k, vals in (("u", (0.3, 0.7)), ("v", (0.3, 0.7)), ("w", (0.8, 1.25))) for val in vals
        ]
        pts = ev.batch(design, TOY_FREQS, "coarse")
        best0 = min(pts, key=lambda p: p.j)
        # … and no single unknown moved from the start reaches all three within 1 Hz
        for u in TOY_UNKNOWNS:
            for x in np.linspace(u.bounds[0], u.bounds[1], 41):
                e = toy_edges({**start, u.name: u.value(float(x))})
                assert max(abs(np.array(e) - want)) > 1.0
        best = landmark_steps(
            ev.batch,
            ev.points,
            best0,
            TOY_UNKNOWNS,
            lambda steps: contact_landmarks(steps, targets),
            LandmarkPlan(TOY_FREQS, "coarse", rounds=12, n=4, good_enough=0.0),
        )
    got = toy_edges(best.values)
    assert max(abs(np.array(got) - want)) <= 1.0, (got, want, best.values)
    assert best.j < best0.j
    assert len(ev.points) <= len(design) + 12 * 4
