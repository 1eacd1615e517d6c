"""Datagrams a link did not take: refused by sender (not its device) or dropped by the kernel before they were read
(the socket's receive buffer full). Together they say whether a link was flooded, and by whom.

A link that accepts only its device's endpoint (the NatNet client, the emulated rig's loopback CAN bus) drops
every other datagram after reading its sender, which costs a few microseconds and no decoding: a flood cannot
make the receive thread do more per datagram. What it can do is fill the socket's buffer, so that the kernel
drops datagrams, the device's among them; :func:`kernel_drops` reads the kernel's own count of those.
"""

from __future__ import annotations

import os
import socket
import sys

__all__ = ["FLOOD_MIN", "ForeignSenders", "kernel_drops"]

FLOOD_MIN = 100  # datagrams not taken (refused + dropped by the kernel) from which a link says it was flooded
MAX_SENDERS = 16  # senders counted one by one; the rest are counted together


class ForeignSenders:
    """Datagrams refused, counted by sender (``host:port``), and the kernel's drops. Updated by one receive
    thread; read by others (plain integer counters: a read may lag by a datagram, never tears)."""

    def __init__(self) -> None:
        self.total = 0  # datagrams refused
        self.kernel_dropped = 0  # datagrams the kernel dropped before they were read (its latest count)
        self._by_sender: dict[str, int] = {}
        self._others = 0  # refused from senders beyond MAX_SENDERS

    def add(self, addr: tuple) -> None:
        """One datagram from ``addr`` refused (bounded work: a dict update)."""
        self.total += 1
        key = f"{addr[0]}:{addr[1]}" if len(addr) >= 2 else str(addr)
        if key in self._by_sender or len(self._by_sender) < MAX_SENDERS:
            self._by_sender[key] = self._by_sender.get(key, 0) + 1
        else:
            self._others += 1

    def note_kernel(self, *socks: socket.socket | None) -> None:
        """Read the kernel's drop counts of ``socks`` now, summed (the last count is kept once they are closed, or
        where the OS does not say)."""
        counts = [kernel_drops(s) for s in socks if s is not None]
        known = [c for c in counts if c is not None]
        if known:
            self.kernel_dropped = max(self.kernel_dropped, sum(known))

    def flood(self) -> str:
        """``flood: N datagrams from host:port dropped …`` once at least :data:`FLOOD_MIN` were not taken; else ""."""
        if self.total + self.kernel_dropped < FLOOD_MIN:
            return ""
        senders = sorted(self._by_sender.items(), key=lambda kv: -kv[1])
        parts = []
        if senders:
            top, n = senders[0]
            parts.append(f"{n} datagrams from {top} dropped")
            rest = sum(c for _, c in senders[1:]) + self._others
            if rest:
                parts.append(f"{rest} from other senders")
        if self.kernel_dropped:
            parts.append(f"{self.kernel_dropped} dropped by the kernel unread (receive buffer full)")
        return "flood: " + "; ".join(parts)


def kernel_drops(sock: socket.socket) -> int | None:
    """How many datagrams the kernel dropped for this UDP socket before they were read (Linux: the ``drops``
    column of ``/proc/net/udp``); None where that cannot be read (another OS, a closed socket)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        inode = os.fstat(sock.fileno()).st_ino
    except (OSError, ValueError):
        return None
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(table, encoding="ascii") as f:
                next(f, None)
                for line in f:
                    cols = line.split()
                    if len(cols) >= 13 and cols[9] == str(inode):
                        return int(cols[12])
        except (OSError, ValueError):
            continue
    return None
