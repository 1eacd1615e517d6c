"""Plain sentences for the operating-system errors of opening a device (what is wrong and what to do), instead
of Python's nested ``[Errno N] …`` texts. Shared by the device drivers and ``beambench doctor``."""

from __future__ import annotations

import errno
import os

CAN_KERNEL_FIX = "sudo modprobe can can_raw, or a kernel built with CAN"
DIALOUT_FIX = "add yourself to the dialout group (sudo usermod -aG dialout $USER), then log out and in again"


def can_kernel_missing() -> str:
    """The sentence for a kernel without SocketCAN (``EAFNOSUPPORT`` on ``socket(AF_CAN)``)."""
    return f"SocketCAN not available on this machine (kernel has no CAN support; try: {CAN_KERNEL_FIX})"


def can_link_up_fix(channel: str, bitrate: int | None) -> str:
    """The command that brings a SocketCAN interface up at the rig's bitrate."""
    return f"sudo ip link set {channel} up type can bitrate {bitrate or 1000000}"


def can_open_problem(interface: str, channel: str, exc: BaseException, bitrate: int | None = None) -> str:
    """Why a CAN bus did not open, as one sentence with what to do."""
    code = exc.errno if isinstance(exc, OSError) else None
    if interface == "socketcan":
        if code == errno.EAFNOSUPPORT:
            return can_kernel_missing()
        if code == errno.ENODEV:
            return f"no CAN interface {channel} on this machine (plug in the CAN adapter; `ip link` lists interfaces)"
        if code == errno.ENETDOWN:
            return f"CAN interface {channel} is down ({can_link_up_fix(channel, bitrate)})"
    if isinstance(exc, OSError) and exc.strerror:
        return f"{interface}:{channel}: {exc.strerror.lower()}"
    return f"{interface}:{channel}: {exc}"


def serial_open_problem(exc: BaseException) -> str:
    """Why a serial port did not open, with what to do: only the system's reason (pyserial repeats the port and
    the errno inside its own message)."""
    code = exc.errno if isinstance(exc, OSError) else None
    if code == errno.ENOENT:
        return "no such device (is the load-cell MCU plugged in? `beambench doctor` lists the serial ports)"
    if code == errno.EACCES:
        return f"permission denied ({DIALOUT_FIX})"
    if code == errno.EBUSY:
        return "in use by another program"
    if isinstance(exc, OSError) and code is not None:
        return _plain(exc)
    return str(exc)


def _plain(exc: OSError) -> str:
    """The system's own reason (``os.strerror``), without the messages wrapped around it."""
    return os.strerror(exc.errno) if exc.errno is not None else str(exc)
