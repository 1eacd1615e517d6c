"""How long a sim run takes on this machine where no measured timing table covers it (walker, release test, a
fixed ``sim.timestep``): build the run's scene and time a short stretch of its physics, here and now."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, replace

from beambench.acquisition.capabilities import WarnsOfModel
from beambench.acquisition.protocol.plan import plan
from beambench.acquisition.protocol.schema import Protocol

PROBE_S = 0.2  # simulated seconds timed (after a short warm-up): ~0.03 s of wall time on the walker
# a walker session's size per second of rig time (mocap, load cells, motor; HDF5): 12.2 MB for walker_track's
# 132.5 s map sweep, checked against a written map in tests/test_tracking.py
SESSION_BYTES_PER_RIG_S = 92e3


@dataclass(frozen=True)
class ProbeEstimate:
    """The stepping time of a whole run, extrapolated from ``wall_per_s`` (wall s per simulated s) at
    ``probe_hz``, weighted by the scene's relative cost per frequency where it has one, over ``parallel``
    segments computed at once."""

    wall_s: float
    wall_per_s: float
    probe_hz: float
    parallel: int
    warnings: tuple[str, ...] = ()  # the scene's own (``WarnsOfModel``), e.g. legs that fold


def probe_run_time(protocol: Protocol) -> ProbeEstimate:
    """Time :data:`PROBE_S` of ``protocol``'s scene at its highest frequency and extrapolate to every step."""
    from beambench.backends.sim import build_scene
    from beambench.session.slices import sim_slice
    from beambench.sim.scenes.drive import CostsByFrequency

    steps = plan(protocol)
    scene = build_scene(sim_slice(protocol))
    track = protocol.track is not None
    if track:  # a profile's frequencies are the controller's, inside its map's: timed at the top of the sweep's
        sweep = protocol.model_copy(update={"track": None})
        probe_hz = max(s.frequency_hz for s in plan(sweep)) if protocol.sweep is not None else 0.0
        probe_hz = probe_hz or protocol.limits.max_frequency_hz
        steps = [replace(s, frequency_hz=probe_hz) for s in steps]
    else:
        probe_hz = max(s.frequency_hz for s in steps)
    scene.set_frequency(probe_hz)
    warm = scene.physics.time + 0.02
    scene.advance_to(warm)
    t0 = time.perf_counter()
    scene.advance_to(warm + PROBE_S)
    wall_per_s = (time.perf_counter() - t0) / PROBE_S

    def relative(hz: float) -> float:
        if not isinstance(scene, CostsByFrequency):
            return 1.0
        return float(scene.step_cost(hz) / scene.step_cost(probe_hz))

    total = sum(s.duration_s * wall_per_s * relative(s.frequency_hz) for s in steps)
    # a closed loop is computed as it runs (nothing ahead): one part; a sweep in sim.segments parts at once
    parallel = 1 if track else max(1, min(protocol.sim.segments, os.cpu_count() or 1))
    warnings = tuple(scene.model_warnings()) if isinstance(scene, WarnsOfModel) else ()
    return ProbeEstimate(total / parallel, wall_per_s, probe_hz, parallel, warnings)
