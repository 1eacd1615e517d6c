"""A CAN bus between two processes on this machine: python-can's ``udp_multicast`` interface, without its echo.

python-can's ``virtual`` bus only reaches buses of the same process; the emulated rig runs its peers (the
emulated ODrive among them) in a process of their own, as real devices are. ``udp_multicast`` crosses
processes, but a bus also receives what it sent itself (python-can cannot switch that off yet), which a real
CAN controller does not do. :class:`LoopbackCanBus` is one end of a two-ended bus: it listens on one UDP port of
the group and sends to the other, so the driver and the emulator see only each other, as on a real bus (the
watchdog is not fed by the emulator's own heartbeats), and no end spends time receiving and dropping its own
frames (a quarter of the driver's traffic: its watchdog feeds and polls).

Each rig gets a group and two ports of its own (:func:`new_channel`), so runs on one machine never hear each other.
"""

from __future__ import annotations

import random
import socket
from typing import Any

from can.interfaces.udp_multicast import UdpMulticastBus

__all__ = ["LoopbackCanBus", "new_channel"]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def new_channel() -> tuple[str, int, int]:
    """A multicast group (administratively scoped, 239.x) and two free UDP ports: one per end of a rig's bus."""
    group = f"239.{random.randint(64, 254)}.{random.randint(0, 255)}.{random.randint(1, 254)}"
    host_port = _free_port()
    peer_port = _free_port()
    while peer_port == host_port:
        peer_port = _free_port()
    return group, host_port, peer_port


class LoopbackCanBus(UdpMulticastBus):
    """One end of a bus on the IPv4 group ``channel``: receives on ``port``, sends to ``send_port``."""

    def __init__(self, channel: str, port: int, send_port: int, **kwargs: Any) -> None:
        if port == send_port:
            raise ValueError("the two ends of a loopback CAN bus need two ports (one end would hear itself)")
        super().__init__(channel=channel, port=port, hop_limit=0, fd=False, **kwargs)
        multicast = getattr(self, "_multicast", None)
        if multicast is None or not hasattr(multicast, "_send_destination"):  # pragma: no cover - python-can change
            self.shutdown()
            raise RuntimeError("python-can's udp_multicast bus has no send destination to set (version changed?)")
        multicast._send_destination = (channel, send_port)
