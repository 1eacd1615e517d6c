"""The simulated load-cell plate: four raw channels from the scene's plate force, and the mocap's sync edges
(``loadcell``)."""

from __future__ import annotations

from beambench.acquisition.forces.loadcell_calibration import default_calibration
from beambench.acquisition.protocol.scenes import scene_info
from beambench.acquisition.streams import LOADCELL, LOADCELL_RATE_HZ, MOCAP, MOCAP_RATE_HZ
from beambench.backends.sim_devices import SimLoadCells
from beambench.backends.sim_streams.registry import SimStreamContext, sim_stream


@sim_stream(LOADCELL)
def build(ctx: SimStreamContext) -> SimLoadCells:
    return SimLoadCells(
        ctx.clock(LOADCELL, LOADCELL_RATE_HZ),
        default_calibration(),
        ctx.clock(MOCAP, MOCAP_RATE_HZ),
        ctx.rng(LOADCELL),
        noise_counts=15.0 if ctx.noise else 0.0,
        plate=scene_info(ctx.sim.scene).plate,
    )
