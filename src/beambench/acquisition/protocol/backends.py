"""The backend catalogue: what each place a protocol can run is, as flags the rest of the code asks (as the scene
catalogue, :mod:`beambench.acquisition.protocol.scenes`, does for rigs), instead of comparing names."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class BackendInfo:
    """One backend (``--backend``, a protocol's ``backend:``)."""

    name: str
    summary: str
    simulated_clock: bool
    """Waiting advances the physics: rig time runs as fast as the computer allows (unless ``--realtime``)."""
    simulates: bool
    """The MuJoCo twin drives it: the protocol's ``sim:`` options apply."""
    devices: bool
    """Real drivers on real transports (CAN, serial, UDP): a CAN traffic log (``--can-log``) applies."""
    model_frame: bool
    """The mocap reports positions in the twin's own frame (no Motive between: nothing to register)."""


BACKEND_INFO: dict[str, BackendInfo] = {
    b.name: b
    for b in (
        BackendInfo("sim", "the MuJoCo twin, simulated devices", True, simulates=True, devices=False, model_frame=True),
        BackendInfo(
            "emulated", "real drivers, emulated peers driven by the twin", False, True, True, model_frame=False
        ),
        BackendInfo(
            "hardware", "real drivers, the lab's devices (rig file)", False, False, devices=True, model_frame=False
        ),
    )
}


def backend_info(name: str) -> BackendInfo:
    """The catalogue entry of backend ``name`` (``KeyError`` for an unknown one: the protocol model refuses it)."""
    return BACKEND_INFO[name]


def backends_with(flag: str) -> list[str]:
    """The backends whose ``flag`` (a :class:`BackendInfo` field) is true, in catalogue order."""
    return [b.name for b in BACKEND_INFO.values() if getattr(b, flag)]
