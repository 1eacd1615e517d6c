"""The walker in ``beambench calibrate sim`` (registers itself, as :mod:`.contact` does; :mod:`.rig`).

Targets: ``rig: walker`` with ``speed_mm_s: {f: v}`` (any number of frequencies; e.g.
``calibration/paper_walker_targets.yaml``) or a walker session (speeds from :mod:`beambench.analysis`).

Unknowns (``benchmarks/bench_walker.py`` sensitivity: one at a time, 23 / 65 Hz): the foot mass moves 65 Hz by
×12 between 20 g and 2 g, the friction turns 23 Hz from +21 to −60 mm/s between 0.3 and 0.8 (with a cliff: two
gaits near 20 Hz between 0.475 and 0.525); rotor inertia, cart and clamp offset move nothing. The offset mass's
radius (the paper gives 40 g, not where it sits) scales the drive force at every frequency. Leg rake and foot
length also move the speed but are geometry one can measure on the robot, so they stay fixed.

Objective: the mean over the target frequencies of |v − v*| / max(|v*|, 20 mm/s) — absolute (L1) relative
errors, so that the friction cliff's overshoot does not dominate, floored at 20 mm/s so a near-zero target does
not — and over the curve's landmarks (``reverses_at_hz``, ``peak_at_hz``: where the speed turns from backward to
forward, where it peaks; :func:`beambench.analysis.walking.speed_curve_shape`) of 0.3·|f − f*| / tolerance_hz,
so that a landmark at its tolerance weighs what a speed at its ± 30 % does (a twin curve without the landmark
counts :data:`MISSING_LANDMARK`). Each evaluation runs every target frequency as one batch from a settled robot
(:func:`beambench.sim.scenes.walker_batch.steady_speeds`: settle 3 s, record 1.5 s); the coarse stage at
dt 1.5e-4 (1.25× cheaper; the contact time constant is then at MuJoCo's 2-step floor), the fine stages at the
scene's converged default (1.2e-4 with a 0.3 ms contact).

Output: ``<name>_params.yaml`` (the prior set with the fitted foot mass, friction and offset radius in its walker block) and ``<name>.yaml`` (the
session's protocol, else the shipped walker sweep, with ``sim.params`` pointing at it).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from beambench.analysis.walking import SpeedCurveShape, speed_curve_shape
from beambench.sim.settings import SimSettings
from beambench.studies.twin_calibration.checks import SPEED_TOLERANCE_FRACTION, TRANSITION_TOLERANCE_HZ, TargetCheck
from beambench.studies.twin_calibration.protocol_out import CalibratedSet, write_calibrated_protocol
from beambench.studies.twin_calibration.rig import CalibratableRig, CalibrationBase, register_rig, stepping_cost
from beambench.studies.twin_calibration.targets import WALKER_LANDMARKS as LANDMARKS
from beambench.studies.twin_calibration.targets import (
    CalibrationInputError,
    Targets,
    walker_session_targets,
    walker_targets,
)
from beambench.studies.unknowns import Override, Unknown, apply_values

if TYPE_CHECKING:
    from beambench.sim.models.params import BeamParams

SPEED_FLOOR_MM_S = 20.0
MISSING_LANDMARK = 3.0  # objective share of a landmark the twin's curve does not have (no reversal, no forward peak)
LANDMARK_NAMES = {"reverses_at_hz": "speed reverses (backward → forward)", "peak_at_hz": "fastest forward at"}
WALKER_UNKNOWNS = (  # the walker's foot mass, friction, offset radius (beambench.sim.scene_params.WalkerParams)
    Unknown(
        "foot_mass",
        0.001,
        0.008,
        unit="kg",
        doc="point mass at each sole (the foot's load)",
        effect=Override(("walker.foot_mass",)),
    ),
    Unknown("friction", 0.35, 0.60, doc="sole–floor Coulomb friction", effect=Override(("walker.friction",))),
    Unknown(
        "eccentric_radius",
        0.003,
        0.0215,
        unit="m",
        doc="radius of the 40 g offset mass on the rotor (the paper gives the mass, not the radius)",
        effect=Override(("walker.eccentric_radius",)),
    ),
)
STAGES: dict[str, dict[str, Any]] = {
    "coarse": {"settle_s": 3.0, "record_s": 1.5, "timestep": 1.5e-4},
    "fine": {"settle_s": 3.0, "record_s": 1.5},  # the protocol's timestep (none given: the scene's)
}


def walker_stage_sim(stage: str, sim: SimSettings) -> SimSettings:
    """The walker's window per stage (the search's settle/record are for the contact rig's maps)."""
    return sim.replace(**STAGES["coarse" if stage == "coarse" else "fine"])


def walker_objective(steps: pd.DataFrame, targets: Targets) -> tuple[float, dict[str, float]]:
    """Mean floored relative error over the target frequencies (module docstring); a missing or diverged
    frequency counts 10."""
    want = targets.scalars["speed_mm_s"]
    got = dict(zip(steps["frequency_hz"].astype(float), steps["body_speed_mm_s"].astype(float)))
    parts: dict[str, float] = {}
    for f, v in want.items():
        g = got.get(float(f), math.nan)
        parts[f"{float(f):g} Hz"] = abs(g - v) / max(abs(v), SPEED_FLOOR_MM_S) if math.isfinite(g) else 10.0
    tol_hz = float(targets.tolerance.get("tolerance_hz", TRANSITION_TOLERANCE_HZ))
    shape = _shape(steps)
    for key in LANDMARKS:
        if key in targets.scalars:
            g = getattr(shape, key)
            err = (
                SPEED_TOLERANCE_FRACTION * abs(g - targets.scalars[key]) / tol_hz if g is not None else MISSING_LANDMARK
            )
            parts[key] = err
    return float(np.mean(list(parts.values()))), parts


def _shape(steps: pd.DataFrame) -> SpeedCurveShape:
    if steps.empty or "body_speed_mm_s" not in steps:
        return SpeedCurveShape(None, None)
    return speed_curve_shape(steps["frequency_hz"].to_numpy(float), steps["body_speed_mm_s"].to_numpy(float))


def _landmark(key: str) -> Callable[[pd.DataFrame], float | None]:
    def measure(steps: pd.DataFrame) -> float | None:
        value: float | None = getattr(_shape(steps), key)
        return value

    return measure


def _speed_at(f: float) -> Callable[[pd.DataFrame], float | None]:
    def measure(steps: pd.DataFrame) -> float | None:
        if steps.empty or "body_speed_mm_s" not in steps:
            return None
        tf = steps["frequency_hz"].to_numpy(float)
        i = int(np.argmin(np.abs(tf - f)))
        return float(steps["body_speed_mm_s"].iloc[i]) if abs(tf[i] - f) <= 1e-6 else None

    return measure


def walker_checks(targets: Targets) -> list[TargetCheck]:
    """The speed at each target frequency within ± ``tolerance_fraction`` (default 30 %) of the target, at least
    that share of the objective's 20 mm/s floor (:mod:`.verdict`)."""
    frac = float(targets.tolerance.get("tolerance_fraction", SPEED_TOLERANCE_FRACTION))
    out = []
    for f, v in sorted(targets.scalars["speed_mm_s"].items()):
        tol = frac * max(abs(v), SPEED_FLOOR_MM_S)
        text = f"± {tol:.3g} mm/s ({100 * frac:g} %)"
        out.append(TargetCheck(f"speed at {f:g} Hz", "speed", float(v), tol, "mm/s", text, _speed_at(float(f))))
    tol_hz = float(targets.tolerance.get("tolerance_hz", TRANSITION_TOLERANCE_HZ))
    for key in LANDMARKS:
        if key in targets.scalars:
            want = float(targets.scalars[key])
            out.append(
                TargetCheck(LANDMARK_NAMES[key], "transition", want, tol_hz, "Hz", f"± {tol_hz:g} Hz", _landmark(key))
            )
    return out


def walker_base(targets: Targets) -> CalibrationBase:
    """The fixed part: the session's protocol (else the shipped walker sweep) simulated as ``beambench run``
    simulates it (one :func:`~beambench.sim.protocol_slice.sim_slice`: leg model, parameter set, twist,
    integrator, timestep); the stages set their own windows (:data:`STAGES`)."""
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.common.resources import shipped_dir
    from beambench.session.slices import sim_slice

    text = targets.protocol_text or (shipped_dir("protocols") / "walker_sweep.yaml").read_text()
    try:
        proto = parse_protocol(text, targets.source)
    except ValueError as exc:
        raise CalibrationInputError(str(exc)) from None
    try:
        sim = sim_slice(proto)
    except ValueError as exc:
        raise CalibrationInputError(f"{targets.source}: {exc}") from None
    return CalibrationBase(sim.model, sim.params, sim.settings, tolerance_mm=sim.tolerance_mm)


def _prior(base: CalibrationBase) -> BeamParams:
    from beambench.sim.models.params import load_params
    from beambench.sim.models.registry import model_family

    return load_params(base.params, model=model_family(base.model))


def walker_boxes(base: CalibrationBase) -> dict[str, tuple[float, float]]:
    """The prior set's physical ranges of the walker's unknowns (``walker.foot_mass``, ``walker.friction`` in its
    ``bounds:``) as their boxes (``CalibratableRig.boxes``); empty for a set without bounds."""
    bounds = _prior(base).bounds
    out = {}
    for u in WALKER_UNKNOWNS:
        b = bounds.get(f"walker.{u.name}")
        if b is not None:
            out[u.name] = (b.min, b.max)
    return out


def simulate_walker(
    base: CalibrationBase, values: dict[str, float], frequencies: list[float], sim: SimSettings
) -> dict:
    """Steady body speeds at ``frequencies`` for the fitted ``values`` (runs in a worker)."""
    from beambench.sim.models.registry import make_beam_model
    from beambench.sim.scene_params import WalkerParams
    from beambench.sim.scenes.walker_batch import steady_speeds

    params = apply_values(_prior(base), WALKER_UNKNOWNS, values)
    beam = make_beam_model(base.model, params)
    wp = WalkerParams.with_overrides(params.walker or params.rig)
    speed, height = steady_speeds(beam, frequencies, wp, settings=sim.replace(nthread=1))  # one thread per worker
    steps = [
        {"frequency_hz": float(f), "body_speed_mm_s": float(v), "body_height_mm": float(z)}
        for f, v, z in zip(frequencies, speed, height)
    ]
    return {"steps": steps, "extras": {}}


def walker_summary(steps: pd.DataFrame) -> dict:
    shape = _shape(steps)
    landmarks = {k: None if (v := getattr(shape, k)) is None else round(v, 1) for k in LANDMARKS}
    speeds = {float(f): round(float(v), 1) for f, v in zip(steps["frequency_hz"], steps["body_speed_mm_s"])}
    return {"speed_mm_s": speeds, **landmarks}


def write_walker_protocol(
    base: CalibrationBase, values: dict[str, float], extras: dict[str, Any], targets: Targets, out_dir: Path, name: str
) -> Path:
    """``out_dir/<name>_params.yaml`` and ``out_dir/<name>.yaml`` (module docstring), through
    :func:`.protocol_out.write_calibrated_protocol`; the walker's block (its walker block, else its rig
    block) carries foot mass, friction and the offset radius."""
    p = apply_values(_prior(base), WALKER_UNKNOWNS, {k: round(float(v), 7) for k, v in values.items()})
    block = "walker" if p.walker else "rig"
    cal = CalibratedSet(
        params=p,
        rig_block=dict(p.rig),
        values=values,
        prior=base.params,
        model=base.model,
        shipped_protocol="walker_sweep.yaml",
        params_note=f"; the {block} block\n# overrides the walker's parameters (beambench.sim.scene_params.WalkerParams).",
        protocol_note=f"sim.params points at the calibrated parameter set (foot mass, friction and offset radius in its {block} block).",
        rig_label="walker",
    )
    return write_calibrated_protocol(cal, targets, out_dir, name)


WALKER_CPU_PER_SIM_S = 0.11  # rod5g legs at their own timestep (sim_backend/step_costs.csv: 0.094–0.119)


def walker_cpu_per_sim_s(base: CalibrationBase, sim: SimSettings) -> float:
    """A walker map's CPU seconds per simulated second on one idle core (the search's budget clock)."""
    from beambench.sim.scene_params import WalkerParams

    return stepping_cost("walker", base.model, sim, WalkerParams().timestep, WALKER_CPU_PER_SIM_S)


@register_rig
def walker_rig() -> CalibratableRig:
    """The walker rig as the calibrator knows it."""
    return CalibratableRig(
        name="walker",
        unknowns=WALKER_UNKNOWNS,
        simulate=simulate_walker,
        objective=walker_objective,
        base=walker_base,
        write=write_walker_protocol,
        summary=walker_summary,
        bracket="foot_mass",
        min_frequency_hz=1.0,
        stage_sim=walker_stage_sim,
        cpu_per_sim_s=walker_cpu_per_sim_s,
        checks=walker_checks,
        boxes=walker_boxes,
        file_targets=walker_targets,
        session_targets=walker_session_targets,
    )
