"""The sim backend's streams by name: each registers how it is built for a run (``@sim_stream(name)``) and
:class:`~beambench.backends.sim.SimRig` builds every registered one, on its own device clock (``sim.clocks``)
and its own noise generator, and samples it from the scene's trajectory after each chunk of physics.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from beambench.backends.sim_devices import DeviceClock, SampledStream
from beambench.common.registry import Registry
from beambench.sim.protocol_slice import SimSlice

__all__ = ["SIM_STREAMS", "SimStreamContext", "SimStreamFactory", "sim_stream"]


@dataclass
class SimStreamContext:
    """What a simulated stream is built from: the protocol's simulation slice, the scene's markers, a noise
    generator and a device clock per stream name (the same ones for every stream that asks: the load cells count
    the mocap clock's exposures)."""

    sim: SimSlice
    markers: tuple[str, ...]
    rngs: dict[str, np.random.Generator]
    _clocks: dict[str, DeviceClock] = field(default_factory=dict)

    @property
    def noise(self) -> bool:
        """Sensor noise on (``sim.noise``)."""
        return self.sim.settings.noise

    def rng(self, stream: str) -> np.random.Generator:
        """The stream's own noise generator (its clock's jitter draws from it too)."""
        return self.rngs[stream]

    def clock(self, stream: str, rate_hz: float) -> DeviceClock:
        """The device clock of ``stream`` (``sim.clocks.<stream>``) sampling at ``rate_hz``; made once."""
        if stream not in self._clocks:
            self._clocks[stream] = DeviceClock(self.sim.clocks.of(stream), rate_hz, self.rng(stream))
        return self._clocks[stream]


SimStreamFactory = Callable[[SimStreamContext], SampledStream]
SIM_STREAMS: Registry[SimStreamFactory] = Registry("sim stream")
"""How the sim backend builds each of its streams, by stream name (the name of the stream's spec)."""


def sim_stream(name: str) -> Callable[[SimStreamFactory], SimStreamFactory]:
    """Register a simulated stream: ``name`` is its stream's name (the session's ``/acquisition/<name>``, the
    key of its clock in ``sim.clocks``)."""
    return SIM_STREAMS.register(name)
