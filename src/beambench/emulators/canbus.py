"""A CAN bus between processes on this machine: python-can's ``udp_multicast`` interface, without its echo.

python-can's ``virtual`` bus only reaches buses of the same process; the emulated rig runs its peers (the
emulated ODrive among them) in a process of their own, as real devices are. ``udp_multicast`` crosses
processes, but every bus also receives what it sent itself (python-can cannot switch that off yet), which a
real CAN controller does not do: :class:`LoopbackCanBus` drops its own frames on receipt, so the driver and the
emulator see only each other, as on a real bus (and the watchdog is not fed by the emulator's own heartbeats).

Each rig gets a group and port of its own (:func:`new_channel`), so runs on one machine never hear each other.
"""

from __future__ import annotations

import random
import socket
import threading
from collections import Counter
from typing import Any

import can
from can.interfaces.udp_multicast import UdpMulticastBus

__all__ = ["LoopbackCanBus", "new_channel"]


def new_channel() -> tuple[str, int]:
    """A multicast group (administratively scoped, 239.x) and a free UDP port for one rig's bus."""
    group = f"239.{random.randint(64, 254)}.{random.randint(0, 255)}.{random.randint(1, 254)}"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    return group, port


def _fingerprint(msg: can.Message) -> tuple[int, bool, bool, bytes]:
    return (msg.arbitration_id, bool(msg.is_extended_id), bool(msg.is_remote_frame), bytes(msg.data))


class LoopbackCanBus(UdpMulticastBus):
    """``udp_multicast`` on ``channel`` (an IPv4 group) and ``port``, minus the echo of its own frames."""

    def __init__(self, channel: str, port: int, **kwargs: Any) -> None:
        super().__init__(channel=channel, port=port, hop_limit=0, fd=False, **kwargs)
        self._sent: Counter[tuple[int, bool, bool, bytes]] = Counter()
        self._sent_lock = threading.Lock()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        with self._sent_lock:
            self._sent[_fingerprint(msg)] += 1
        super().send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        msg, filtered = super()._recv_internal(timeout)
        if msg is None:
            return msg, filtered
        fp = _fingerprint(msg)
        with self._sent_lock:
            if self._sent[fp] > 0:  # our own frame coming back: a real controller would not receive it
                self._sent[fp] -= 1
                if not self._sent[fp]:
                    del self._sent[fp]
                return None, filtered
        return msg, filtered
