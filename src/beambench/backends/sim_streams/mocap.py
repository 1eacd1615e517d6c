"""The simulated motion capture: the scene's markers as Motive labels them (``mocap``)."""

from __future__ import annotations

from beambench.acquisition.streams import MOCAP, MOCAP_RATE_HZ
from beambench.backends.sim_devices import SimMocap
from beambench.backends.sim_streams.registry import SimStreamContext, sim_stream


@sim_stream(MOCAP)
def build(ctx: SimStreamContext) -> SimMocap:
    return SimMocap(ctx.markers, ctx.clock(MOCAP, MOCAP_RATE_HZ), ctx.rng(MOCAP), noise_m=1e-4 if ctx.noise else 0.0)
