"""The ``mocap`` stream: OptiTrack Motive over NatNet (:mod:`beambench.devices.natnet`), wired by the rig file's
``natnet:`` section; its emulated peer is a Motive server on UDP loopback
(:mod:`beambench.devices.natnet.emulated_motive`). The driver and the peer are imported when built (a rig file is
checked without them)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from beambench.acquisition.batch import Frame
from beambench.acquisition.capabilities import Stream
from beambench.acquisition.streams import MOCAP
from beambench.common.yaml_config import ConfigError
from beambench.devices.streams.registry import DeviceContext, device_stream

if TYPE_CHECKING:
    from beambench.devices.peer import EmulatedPeer, PeerContext


def _motive(ctx: PeerContext) -> EmulatedPeer:
    from beambench.devices.natnet.emulated_motive import MotivePeer

    return MotivePeer(ctx)


def _ping(section: Any) -> dict[str, Any]:
    from beambench.devices.natnet import client as natnet

    config = natnet.NatNetConfig.from_mapping(section.model_dump(exclude={"markers"}))
    return {"found": True, **natnet.ping(config)}


@device_stream(
    MOCAP,
    section="natnet",
    peer=_motive,
    injections=("mocap_drop", "mocap_occlude"),
    ping=_ping,
    label="mocap (NatNet)",
)
def build(ctx: DeviceContext) -> Stream:
    """The mocap in the frame of the rig file's ``geometry:``, wired to the scene's markers (each must have a source
    in ``natnet.markers``)."""
    from beambench.devices.natnet.mocap import NatNetMocap

    frame = Frame(**ctx.rig.geometry.model_dump())
    section = ctx.section.model_dump()
    silence = section.pop("silence_timeout_s", None)
    missing = [m for m in ctx.markers if m not in section["markers"]]
    if missing:
        raise ConfigError("<rig file>", "natnet.markers", sorted(section["markers"]), f"no source for {missing}")
    return NatNetMocap.from_rig(section, markers=ctx.markers, frame=frame, silence_timeout_s=silence)
