"""How a device stream registers itself: ``@device_stream(name, ...)`` on its driver's factory, in the stream's own
module of :mod:`beambench.devices.streams` (whose import list loads them all, in order), with its rig-file section
and its emulated peer: the device described once."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from beambench.acquisition.capabilities import Stream
from beambench.acquisition.protocol.schema import RigFile, RigSection
from beambench.common.registry import Registry

if TYPE_CHECKING:
    from beambench.devices.peer import EmulatedPeer, PeerContext

__all__ = ["DEVICE_STREAMS", "DeviceContext", "DeviceStream", "device_stream"]


@dataclass(frozen=True)
class DeviceContext:
    """What a stream's driver is built from: the whole rig file, the stream's own section of it, and the markers
    the mocap is wired to (the scene's)."""

    rig: RigFile
    section: Any
    markers: tuple[str, ...]


StreamFactory = Callable[[DeviceContext], Stream]
PeerFactory = Callable[["PeerContext"], "EmulatedPeer"]
Ping = Callable[[Any], dict[str, Any]]
"""Asks the device wired by its rig-file section who it is (``found``: whether it answered, and what it said)."""


@dataclass(frozen=True)
class DeviceStream:
    """One registered stream of the device rigs: how its driver is built, where it is wired, and the emulated peer
    that speaks its wire protocol on this machine."""

    name: str
    build: StreamFactory
    section: str
    """The rig file's section that wires it."""
    wiring: type[RigSection] | None
    """That section's model, when the stream brings its own (None: a section :class:`RigFile` has)."""
    peer: PeerFactory | None
    """Builds the emulated peer: a class of the stream's module, or a function that imports a larger peer's module
    (so that only the emulated peers' process loads it)."""
    injections: tuple[str, ...]
    """The fault-injection keys its peer takes (``build_emulated_rig(inject=...)``)."""
    ping: Ping | None
    label: str
    """What ``beambench devices`` calls it."""

    def ask(self, rig: Any) -> dict[str, Any] | None:
        """Its device's answer to :attr:`ping`, wired by ``rig``'s section (``found``: whether it answered); a
        failure to reach it is the answer (``found`` False and the ``error``), never raised; None: no ping."""
        if self.ping is None:
            return None
        try:
            return self.ping(getattr(rig, self.section))
        except Exception as exc:  # an absent or broken device is an answer, never the caller's crash
            return {"found": False, "error": str(exc)}


DEVICE_STREAMS: Registry[DeviceStream] = Registry("device stream")
"""The streams of the hardware and emulated rigs, by name (the rig's identity key and ``rig.<name>``), in the order of
the import list of :mod:`beambench.devices.streams`."""


def device_stream(
    name: str,
    *,
    section: str | None = None,
    wiring: type[RigSection] | None = None,
    peer: PeerFactory | None = None,
    injections: tuple[str, ...] = (),
    ping: Ping | None = None,
    label: str | None = None,
) -> Callable[[StreamFactory], StreamFactory]:
    """Register a stream of the device rigs: its driver's factory (decorated), the rig-file ``section`` that wires
    it (default: ``name``) with its ``wiring`` model if :class:`RigFile` has no such section, its emulated
    ``peer`` (the emulated rig starts it and builds the driver against it through the same factory) with the
    fault ``injections`` it takes, and how ``beambench devices`` pings it (shown as ``label``, default ``name``)."""

    def add(make: StreamFactory) -> StreamFactory:
        DEVICE_STREAMS.check_free(name)
        where = section or name
        if (wiring is None) != (where in RigFile.model_fields):
            why = "has no section" if wiring is None else "already has a section"
            raise ValueError(f"device stream {name!r}: the rig file {why} {where!r} (wiring= is for a new section)")
        DEVICE_STREAMS.add(name, DeviceStream(name, make, where, wiring, peer, tuple(injections), ping, label or name))
        return make

    return add
