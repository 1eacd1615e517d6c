"""Datagrams with the kernel's receive time, on the host's monotonic clock.

A receive thread that sleeps a few milliseconds to read several datagrams per wake-up (a large share of the
CPU cost at 360 Hz is waking up) would otherwise stamp them late and all alike. Linux stamps each datagram as
it arrives (``SO_TIMESTAMPNS``, on ``CLOCK_REALTIME``); :func:`recv_stamped` returns that time moved onto
``time.monotonic_ns()``. Where the option is missing (another OS, a platform with other constants) the time is
taken when the datagram is read, as before.
"""

from __future__ import annotations

import socket
import struct
import sys
import time

__all__ = ["enable_receive_timestamps", "mono_minus_real_ns", "recv_stamped"]

# <asm-generic/socket.h>: SO_TIMESTAMPNS_OLD = 35 = SCM_TIMESTAMPNS (x86, arm, riscv …; not parisc/sparc/alpha)
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_TIMESPEC = struct.Struct("@qq")
_ANC_SPACE = socket.CMSG_SPACE(_TIMESPEC.size) if hasattr(socket, "CMSG_SPACE") else 0
_MAX_AGE_NS = 1_000_000_000  # a stamp older than this (or in the future) is not believed: the wall clock stepped


def mono_minus_real_ns(tries: int = 3) -> int:
    """``time.monotonic_ns() - time.time_ns()`` now, read so that a preemption between the two clock reads does
    not skew it: the wall clock is read between two monotonic reads, and the tightest of ``tries`` brackets is
    kept (a thread preempted between two plain reads on a busy machine was off by a millisecond)."""
    best_width, best = -1, 0
    for _ in range(tries):
        a = time.monotonic_ns()
        real = time.time_ns()
        b = time.monotonic_ns()
        if best_width < 0 or b - a < best_width:
            best_width, best = b - a, (a + b) // 2 - real
    return best


def enable_receive_timestamps(sock: socket.socket) -> bool:
    """Ask the kernel to stamp every datagram ``sock`` receives; False where it cannot."""
    if not sys.platform.startswith("linux") or not _ANC_SPACE:
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def recv_stamped(sock: socket.socket, bufsize: int, stamped: bool, mono_minus_real_ns: int) -> tuple[bytes, tuple, int]:
    """One datagram: ``(data, sender address, receive time in monotonic ns)``.

    ``mono_minus_real_ns`` is :func:`mono_minus_real_ns` read by the caller once per pass (the two clocks drift
    apart by microseconds a second at most). Raises what ``socket.recvfrom`` raises."""
    if not stamped:
        data, addr = sock.recvfrom(bufsize)
        return data, addr, time.monotonic_ns()
    data, anc, _flags, addr = sock.recvmsg(bufsize, _ANC_SPACE)
    now = time.monotonic_ns()
    for level, kind, payload in anc:
        if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(payload) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(payload)
            t = sec * 1_000_000_000 + nsec + mono_minus_real_ns
            if now - _MAX_AGE_NS <= t <= now:
                return data, addr, t
    return data, addr, now
