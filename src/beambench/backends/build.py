"""Build a :class:`~beambench.acquisition.capabilities.Rig` for a backend: sim (MuJoCo), emulated (real
drivers against wire-level emulated peers driven by the sim) or hardware (real drivers, real devices from the
rig file), each from its slices of the protocol (:class:`RigSlices`, cut by :mod:`beambench.session.slices`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from beambench.acquisition.capabilities import Rig
from beambench.acquisition.protocol.backends import BACKEND_INFO, backend_info
from beambench.acquisition.protocol.schema import Backend
from beambench.common.registry import Registry
from beambench.sim.protocol_slice import SimSlice


@dataclass(frozen=True)
class RigSlices:
    """What a backend builds its rig from."""

    sim: SimSlice | None
    """The simulation (sim and emulated backends; None on hardware)."""
    markers: tuple[str, ...]
    """The markers the mocap is wired to (hardware; the emulated peers report their scene's own)."""
    tracking: bool = False
    """A closed-loop speed profile (``track:``): the sim computes nothing ahead."""


@dataclass(frozen=True)
class BuildOptions:
    """What a backend's rig builder may use besides the slices."""

    realtime: bool = False
    rig_file: Path | None = None
    can_log: Path | None = None
    scheduler: str | None = None
    """A Dask scheduler's address: the sim computes a segmented sweep's later parts on that cluster."""


RigBuilder = Callable[[RigSlices, BuildOptions], Rig]
BUILDERS: Registry[RigBuilder] = Registry("rig builder of backend")
"""Each backend's rig builder, by backend name (:data:`beambench.acquisition.protocol.backends.BACKEND_INFO`)."""


def rig_builder(backend: str) -> Callable[[RigBuilder], RigBuilder]:
    """Register how ``backend`` (a name of the backend catalogue) builds its rig."""
    if backend not in BACKEND_INFO:
        raise ValueError(f"backend {backend!r} is not in the backend catalogue ({', '.join(BACKEND_INFO)})")
    return BUILDERS.register(backend)


def build_rig(
    slices: RigSlices,
    backend: Backend,
    realtime: bool = False,
    rig_file: Path | None = None,
    can_log: Path | None = None,
    scheduler: str | None = None,
) -> Rig:
    """The rig for ``backend``; drivers are imported lazily so the sim needs no hardware packages."""
    if backend_info(backend).simulates and slices.sim is None:
        raise ValueError(f"the {backend} backend needs a simulation slice")
    return BUILDERS[backend](slices, BuildOptions(realtime, rig_file, can_log, scheduler))


@rig_builder("hardware")
def _hardware(slices: RigSlices, opts: BuildOptions) -> Rig:
    from beambench.backends.hardware import build_device_rig

    return build_device_rig(slices.markers, rig_file=opts.rig_file, can_log=opts.can_log)


@rig_builder("sim")
def _sim(slices: RigSlices, opts: BuildOptions) -> Rig:
    from beambench.backends.sim import build_sim_rig

    assert slices.sim is not None  # build_rig checked it
    # closed-loop tracking commands every few ms: a chunk computed ahead would only be undone
    return build_sim_rig(slices.sim, realtime=opts.realtime, prefetch=not slices.tracking, scheduler=opts.scheduler)


@rig_builder("emulated")
def _emulated(slices: RigSlices, opts: BuildOptions) -> Rig:
    from beambench.backends.emulated import build_emulated_rig

    assert slices.sim is not None
    return build_emulated_rig(slices.sim, can_log=opts.can_log, rig_file=opts.rig_file)
