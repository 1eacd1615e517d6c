"""The ``loadcells`` stream: the load-cell plate's MCU on a serial port (:mod:`beambench.devices.loadcell`), wired by
the rig file's ``loadcell:`` section; its emulated peer is the MCU on a pseudo-terminal
(:mod:`beambench.devices.loadcell.emulated_mcu`). The driver (pyserial) and the peer are imported when built (a rig
file is checked without them)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from beambench.acquisition.capabilities import Stream
from beambench.devices.streams.registry import DeviceContext, device_stream

if TYPE_CHECKING:
    from beambench.devices.peer import EmulatedPeer, PeerContext


def _mcu(ctx: PeerContext) -> EmulatedPeer:
    from beambench.devices.loadcell.emulated_mcu import LoadCellPeer

    return LoadCellPeer(ctx)


def _ping(section: Any) -> dict[str, Any]:
    from beambench.devices.loadcell.driver import ping

    lc = ping(section.port, section.baudrate)
    return {"found": lc.ok, **{k: v for k, v in vars(lc).items() if k not in ("ok", "stats")}}


@device_stream(
    "loadcells",
    section="loadcell",
    peer=_mcu,
    injections=("loadcell_crc", "loadcell_drop", "loadcell_garbage", "loadcell_stop_s"),
    ping=_ping,
    label="load cells (serial)",
)
def build(ctx: DeviceContext) -> Stream:
    """The load cells on the section's port, at its baud rate, with its silence timeout."""
    from beambench.devices.loadcell.driver import SerialLoadCells

    lc = ctx.section
    return SerialLoadCells(lc.port, lc.baudrate, silence_timeout_s=lc.silence_timeout_s)
