"""Build a :class:`~beambench.acquisition.capabilities.Rig` for a backend: sim (MuJoCo), emulated (real
drivers against wire-level emulated peers driven by the sim) or hardware (real drivers, real devices from the
rig file)."""

from __future__ import annotations

from pathlib import Path

from beambench.acquisition.capabilities import Rig
from beambench.acquisition.config import Backend, Protocol


def build_rig(
    protocol: Protocol,
    backend: Backend,
    realtime: bool = False,
    rig_file: Path | None = None,
    can_log: Path | None = None,
) -> Rig:
    """The rig for ``backend``; drivers are imported lazily so the sim needs no hardware packages."""
    if backend == "sim":
        from beambench.backends.sim import build_sim_rig
        from beambench.sim.protocol_slice import sim_slice

        # closed-loop tracking commands every few ms: a chunk computed ahead would only be undone
        return build_sim_rig(sim_slice(protocol), realtime=realtime, prefetch=protocol.track is None)
    if backend == "emulated":
        from beambench.backends.emulated import build_emulated_rig

        return build_emulated_rig(protocol, can_log=can_log, rig_file=rig_file)
    from beambench.backends.hardware import build_device_rig

    return build_device_rig(protocol, rig_file=rig_file, can_log=can_log)
