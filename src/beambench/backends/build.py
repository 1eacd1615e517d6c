"""Build a :class:`~beambench.acquisition.capabilities.Rig` for a backend: sim (MuJoCo), emulated (real
drivers against wire-level emulated peers driven by the sim) or hardware (real drivers, real devices from the
rig file), each from its slices of the protocol (:class:`RigSlices`, cut by :mod:`beambench.session.slices`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from beambench.acquisition.capabilities import Rig
from beambench.acquisition.protocol.schema import Backend
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


def build_rig(
    slices: RigSlices,
    backend: Backend,
    realtime: bool = False,
    rig_file: Path | None = None,
    can_log: Path | None = None,
) -> Rig:
    """The rig for ``backend``; drivers are imported lazily so the sim needs no hardware packages."""
    if backend == "hardware":
        from beambench.backends.hardware import build_device_rig

        return build_device_rig(slices.markers, rig_file=rig_file, can_log=can_log)
    if slices.sim is None:
        raise ValueError(f"the {backend} backend needs a simulation slice")
    if backend == "sim":
        from beambench.backends.sim import build_sim_rig

        # closed-loop tracking commands every few ms: a chunk computed ahead would only be undone
        return build_sim_rig(slices.sim, realtime=realtime, prefetch=not slices.tracking)
    from beambench.backends.emulated import build_emulated_rig

    return build_emulated_rig(slices.sim, can_log=can_log, rig_file=rig_file)
