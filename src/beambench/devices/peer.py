"""What a device's emulated peer is: the other end of the device's wire protocol, on this machine
(:class:`EmulatedPeer`), made from a :class:`PeerContext` (the physics it measures, its clock model, seed, noise and
the faults to inject). A device stream registers its peer beside its driver (``@device_stream(name, peer=...)``,
:mod:`beambench.devices.streams.registry`); the emulated backend starts every registered one in the peers' process."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from beambench.acquisition.clocks import DeviceClocks
from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration, default_calibration
from beambench.acquisition.protocol.schema import ClockModel

__all__ = ["EmulatedPeer", "GoesSilent", "PeerContext", "PhysicsSource", "StillPhysics", "Wiring"]

Wiring = dict[str, dict[str, Any]]
"""Rig-file sections (``natnet``, ``loadcell``, ...) → the fields that reach a peer (its address, port, path)."""


class PhysicsSource(Protocol):
    """What a peer measures: the scene's markers (z up, m) and the plate's force (normal, tangential; N)."""

    @property
    def markers(self) -> tuple[str, ...]: ...

    def positions(self, t: float) -> np.ndarray:
        """The markers now [M, 3]."""
        ...

    def positions_at(self, host_s: float) -> np.ndarray:
        """The markers at host monotonic time ``host_s`` [M, 3]."""
        ...

    def force(self, t: float) -> tuple[float, float]:
        """The plate's force now."""
        ...


@dataclass(frozen=True)
class StillPhysics:
    """A rig at rest: every marker at the origin, no force (``beambench devices --emulate`` pings this)."""

    markers: tuple[str, ...]

    def positions(self, t: float) -> np.ndarray:
        return np.zeros((len(self.markers), 3))

    def positions_at(self, host_s: float) -> np.ndarray:
        return self.positions(0.0)

    def force(self, t: float) -> tuple[float, float]:
        return 0.0, 0.0


@dataclass(frozen=True)
class PeerContext:
    """What every peer is built from."""

    physics: PhysicsSource
    clocks: DeviceClocks = field(default_factory=DeviceClocks)
    """The protocol's ``sim.clocks``: :meth:`clock` reads a stream's."""
    seed: int = 0
    noise: bool = False
    inject: Mapping[str, Any] = field(default_factory=dict)
    """Faults to inject, by the keys the stream registered (``injections=``)."""
    calibration: LoadCellCalibration = field(default_factory=default_calibration)
    """The load cells' counts per newton (what a force-measuring peer sends)."""

    def clock(self, stream: str) -> ClockModel:
        """The device clock of the stream named ``stream`` (``sim.clocks.<stream>``; ideal if not given)."""
        return self.clocks.of(stream)


class EmulatedPeer(Protocol):
    """A device on this machine. ``open`` binds its transport and says how a driver reaches it; ``start`` makes it
    send (once every driver listens); ``stop`` stops sending; ``report`` says what it sent and injected (plain
    data: it crosses a process boundary); ``close`` releases the transport."""

    def open(self) -> Wiring: ...

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def report(self) -> dict[str, Any]: ...

    def close(self) -> None: ...


@runtime_checkable
class GoesSilent(Protocol):
    """A peer that can stop sending for a while (a real network outage), as a test asks."""

    def outage(self, seconds: float) -> None: ...
