"""A CAN bus between two processes on this machine: python-can frames in UDP datagrams on the loopback interface.

python-can's ``virtual`` bus only reaches buses of the same process; the emulated rig runs its peers (the
emulated ODrive among them) in a process of their own, as real devices are. :class:`LoopbackCanBus` is one end of
a two-ended bus: one UDP socket bound to ``127.0.0.1`` (never a wider interface), sending to the other end's
socket and accepting datagrams from that socket only, so the driver and the emulator hear only each other, as on a
real bus (the watchdog is not fed by the emulator's own heartbeats). A datagram from any other sender (another
program on this machine) is dropped and counted (``forged``), one that is not a python-can frame too
(``garbled``) — as the NatNet client does with its mocap datagrams. Refused datagrams are counted by sender and the
kernel's drops (a buffer filled by a flood) read, so that a flood is named (:meth:`flood`). The receive buffer is
asked for :data:`RECEIVE_BUFFER` bytes, so that a burst of junk does not push the device's frames out. Frames are
packed as python-can's ``udp_multicast`` interface packs them.

Each end binds a free port of its own (port 0); the other end learns it in the rig's handshake (:meth:`connect`).
"""

from __future__ import annotations

import select
import socket
import time
from typing import Any

import can
from can.interfaces.udp_multicast.utils import pack_message, unpack_message

from beambench.devices.foreign import ForeignSenders

__all__ = ["LOOPBACK", "LoopbackCanBus"]

LOOPBACK = "127.0.0.1"
MAX_DATAGRAM = 4096
RECEIVE_BUFFER = 4 << 20  # asked for; the kernel caps it at net.core.rmem_max


class LoopbackCanBus(can.BusABC):
    """One end of a two-ended bus on ``host`` (loopback): receives on ``port`` (0: a free one), sends to and
    accepts only ``peer_port`` (set now or by :meth:`connect` once the other end is known)."""

    def __init__(self, port: int = 0, peer_port: int | None = None, host: str = LOOPBACK, **kwargs: Any) -> None:
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)
            self._sock.bind((host, port))
        except OSError as exc:
            self._sock.close()
            raise can.CanInitializationError(f"cannot bind the loopback CAN bus to {host}:{port}: {exc}") from exc
        self.host = host
        self.port = int(self._sock.getsockname()[1])
        self._peer: tuple[str, int] | None = None
        self._packed: dict[int, tuple[can.Message, bytes]] = {}  # keep_packed(): id -> (message, its datagram)
        self.received = 0  # frames accepted from the other end
        self.refused = ForeignSenders()  # datagrams from any other sender (dropped), by sender; the kernel's drops
        self.garbled = 0  # datagrams from the other end that are no python-can frame: dropped
        self.channel_info = f"loopback UDP {host}:{self.port}"
        super().__init__(channel=f"{host}:{self.port}", **kwargs)
        if peer_port is not None:
            self.connect(peer_port)

    def connect(self, peer_port: int) -> None:
        """The other end's port: frames go there, and only datagrams from there are accepted."""
        if peer_port == self.port:
            raise ValueError("the two ends of a loopback CAN bus need two ports (one end would hear itself)")
        self._peer = (self.host, int(peer_port))

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        ready, _, _ = select.select([self._sock], [], [], timeout)
        if not ready:
            return None, False
        data, sender = self._sock.recvfrom(MAX_DATAGRAM)
        if self._peer is None or sender[:2] != self._peer:
            self.refused.add(sender)
            return None, False
        try:
            msg = unpack_message(data, check=True)
        except Exception:  # msgpack's and python-can's errors alike: not a frame
            self.garbled += 1
            return None, False
        msg.timestamp = time.time()  # the receive time (the driver maps it to the monotonic clock)
        self.received += 1
        return msg, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._peer is None:
            raise can.CanOperationError("the loopback CAN bus has no other end yet")
        try:
            kept = self._packed.get(id(msg))
            self._sock.sendto(kept[1] if kept is not None and kept[0] is msg else pack_message(msg), self._peer)
        except OSError as exc:
            raise can.CanOperationError(f"loopback CAN send failed: {exc}") from exc

    def keep_packed(self, msg: can.Message) -> None:
        """Pack ``msg`` now: sending this very message later needs no memory (an idle frame, sent when the
        process may have none left)."""
        self._packed[id(msg)] = (msg, pack_message(msg))

    @property
    def forged(self) -> int:
        """Datagrams from any sender but the other end (dropped)."""
        return self.refused.total

    @property
    def kernel_dropped(self) -> int:
        """Datagrams the kernel dropped before this end read them (its receive buffer full)."""
        self._note_kernel()
        return self.refused.kernel_dropped

    def flood(self) -> str:
        """``flood: N datagrams from host:port dropped …`` when this end was flooded, else ""."""
        self._note_kernel()
        return self.refused.flood()

    def _note_kernel(self) -> None:
        if self._sock.fileno() >= 0:  # the last count read stays after the socket closed
            self.refused.note_kernel(self._sock)

    def fileno(self) -> int:
        return self._sock.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self._note_kernel()  # the last count, before the socket is gone
        self._sock.close()
