"""How long a sim run takes where no measured timing table covers it (the contact twin's rod, the walker, the
release test, a fixed ``sim.timestep``), without loading MuJoCo: from the shipped table of measured stepping costs
(``sim_backend/step_costs.csv``: CPU seconds per simulated second by scene, model, parameter set, integrator,
timestep and drive frequency), which :func:`measure_step_costs` makes by timing short stretches of a protocol's
physics (``python benchmarks/bench_step_costs.py --ship``)."""

from __future__ import annotations

import csv
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from beambench.acquisition.capabilities import WarnsOfModel
from beambench.acquisition.protocol.plan import Step, plan
from beambench.acquisition.protocol.schema import Protocol
from beambench.sim.models.params import SIM_BACKEND_DIR
from beambench.sim.protocol_slice import SimSlice

PROBE_S = 0.2  # simulated seconds timed per frequency (after a short warm-up)
COST_FREQUENCIES = 6  # drive frequencies timed across a protocol's range
COSTS_FILE = SIM_BACKEND_DIR / "step_costs.csv"
COST_FIELDS = ("scene", "model", "params", "integrator", "timestep", "frequency_hz", "cpu_s_per_sim_s", "warnings")
# a walker session's size per second of rig time (mocap, load cells, motor; HDF5): 12.2 MB for walker_track's
# 132.5 s map sweep, checked against a written map in tests/test_tracking.py
SESSION_BYTES_PER_RIG_S = 92e3


@dataclass(frozen=True)
class CostEstimate:
    """The stepping time of a whole run (``seconds``) from the measured costs of its physics: ``cpu_per_s`` CPU s
    per simulated second at ``at_hz`` (its highest frequency), weighted per step by the cost at its frequency, over
    ``parallel`` segments computed at once; ``params``: the parameter set the costs were measured with."""

    seconds: float
    cpu_per_s: float
    at_hz: float
    parallel: int
    params: str
    warnings: tuple[str, ...] = ()  # the scene's own when it was measured (``WarnsOfModel``), e.g. legs that fold


def cost_key(sim: SimSlice) -> dict[str, str]:
    """What a measured cost is filed under: the scene, model, parameter set, integrator and timestep (``auto``: the
    scene's own per frequency)."""
    h = sim.settings.timestep
    step = "auto" if h is None else ",".join(f"{x:g}" for x in np.atleast_1d(np.asarray(h, float)))
    return {
        "scene": sim.scene,
        "model": sim.model,
        "params": sim.params,
        "integrator": sim.integrator,
        "timestep": step,
    }


def _runs(protocol: Protocol) -> tuple[list[Step], list[float]]:
    """The steps a run steps through, at the frequencies its physics runs (a ``track:`` profile's are the
    controller's, inside its map's: counted at the top of the sweep), and the frequencies to time."""
    steps = plan(protocol)
    if protocol.track is not None:
        sweep = plan(protocol.model_copy(update={"track": None})) if protocol.sweep is not None else []
        top = max((s.frequency_hz for s in sweep), default=0.0) or protocol.limits.max_frequency_hz
        return [replace(s, frequency_hz=top) for s in steps], [top]
    freqs = sorted({abs(s.frequency_hz) for s in steps})
    pick = np.unique(np.round(np.linspace(0, len(freqs) - 1, min(COST_FREQUENCIES, len(freqs))))).astype(int)
    return steps, [freqs[i] for i in pick]


def measure_step_costs(protocol: Protocol) -> list[dict[str, str]]:
    """Time :data:`PROBE_S` of ``protocol``'s scene (built as its run builds it: loads MuJoCo) at up to
    :data:`COST_FREQUENCIES` of its frequencies: rows of :data:`COST_FIELDS` for ``sim_backend/step_costs.csv``."""
    from beambench.backends.sim import build_scene
    from beambench.session.slices import sim_slice

    sim = sim_slice(protocol)
    _, freqs = _runs(protocol)
    scene = build_scene(sim)
    try:
        warnings = " | ".join(scene.model_warnings()) if isinstance(scene, WarnsOfModel) else ""
        rows = []
        for hz in freqs:
            scene.set_frequency(hz)
            warm = scene.physics.time + 0.02
            scene.advance_to(warm)
            c0 = time.process_time()
            scene.advance_to(warm + PROBE_S)
            cpu = (time.process_time() - c0) / PROBE_S
            rows.append(
                {**cost_key(sim), "frequency_hz": f"{hz:g}", "cpu_s_per_sim_s": f"{cpu:.4g}", "warnings": warnings}
            )
    finally:
        scene.physics.close()
    return rows


def read_costs(path: Path = COSTS_FILE) -> list[dict[str, str]]:
    """The measured costs (rows of :data:`COST_FIELDS`); none where the file is missing."""
    try:
        with open(path, newline="") as f:
            return list(csv.DictReader(f))
    except FileNotFoundError:
        return []


def table_run_time(protocol: Protocol, sim: SimSlice, costs: list[dict[str, str]] | None = None) -> CostEstimate | None:
    """The stepping time of ``protocol``'s run from the measured costs (``costs``, None: :func:`read_costs`) of its
    scene, model, integrator and timestep (its own parameter set's where measured, else another set's of the same
    model), interpolated in frequency; None where nothing measured covers it."""
    key = cost_key(sim)
    same = [
        r for r in (read_costs() if costs is None else costs) if all(r[k] == v for k, v in key.items() if k != "params")
    ]
    own = [r for r in same if r["params"] == key["params"]]
    rows = own or [r for r in same if r["params"] == same[0]["params"]] if same else []
    if not rows:
        return None
    rows.sort(key=lambda r: float(r["frequency_hz"]))
    f = np.array([float(r["frequency_hz"]) for r in rows])
    cost = np.array([float(r["cpu_s_per_sim_s"]) for r in rows])
    steps, _ = _runs(protocol)
    total = sum(s.duration_s * float(np.interp(abs(s.frequency_hz), f, cost)) for s in steps)
    top = max((abs(s.frequency_hz) for s in steps), default=0.0)
    # a closed loop is computed as it runs (nothing ahead): one part; a sweep in sim.segments parts at once
    parallel = 1 if protocol.track is not None else max(1, min(protocol.sim.segments, os.cpu_count() or 1))
    warnings = tuple(w for w in rows[0].get("warnings", "").split(" | ") if w)
    return CostEstimate(total / parallel, float(np.interp(top, f, cost)), top, parallel, rows[0]["params"], warnings)
