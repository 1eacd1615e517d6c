"""Build a :class:`~beambench.devices.base.Rig` for a backend: sim (MuJoCo), emulated (real drivers against
wire-level emulated peers driven by the sim) or hardware (real drivers, real devices from the rig file)."""

from __future__ import annotations

from pathlib import Path

from beambench.config import ConfigError, Protocol
from beambench.devices.base import Rig

BACKENDS = ("sim", "emulated", "hardware")


def build_rig(protocol: Protocol, backend: str, realtime: bool = False, rig_file: Path | None = None, **options: object) -> Rig:
    """The rig for ``backend``; drivers are imported lazily so the sim needs no hardware packages."""
    if backend == "sim":
        from beambench.sim.rig import build_sim_rig

        return build_sim_rig(protocol, realtime=realtime)
    if backend in ("emulated", "hardware"):
        try:
            from beambench.hardware_rig import build_device_rig
        except ModuleNotFoundError as exc:
            if exc.name != "beambench.hardware_rig":
                raise
            raise ConfigError("<cli>", "--backend", backend, "not available in this build yet") from None
        return build_device_rig(protocol, backend, rig_file=rig_file, **options)
    raise ConfigError("<cli>", "--backend", backend, f"must be one of {', '.join(BACKENDS)}")
