"""The host's own stall, told apart from the ODrive's silence, and what is said of an idle the ODrive did not
confirm: shared by the CAN and the USB driver.

Each driver has a thread that wakes every few tens of milliseconds (the CAN feeder, the USB poller). A gap between
its wake-ups longer than the link timeout (or the ODrive's watchdog timeout, if shorter) while the motor is armed
means this process got no CPU time (SIGSTOP, a debugger, heavy swapping), whatever the ODrive did meanwhile.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["HostStall", "idle_not_confirmed"]


@dataclass
class HostStall:
    """The longest stall of the host seen since the motor was armed (``stall_ns``, 0: none). Not thread-safe: its
    owner calls it under its own lock."""

    last_tick_ns: int | None = None  # the periodic thread's last wake-up
    stall_ns: int = 0

    def note(self, now_ns: int, armed: bool, timeout_s: float, watchdog_s: float | None) -> None:
        """Record the gap since the last tick as a stall if it is longer than ``timeout_s`` (or ``watchdog_s``, if
        set and shorter: the watchdog idled the axis meanwhile) while ``armed``."""
        gap = now_ns - self.last_tick_ns if self.last_tick_ns is not None else 0
        if armed and gap > min(timeout_s, watchdog_s or math.inf) * 1e9:
            self.stall_ns = max(self.stall_ns, gap)

    def tick(self, now_ns: int) -> None:
        """The periodic thread woke up at ``now_ns``."""
        self.last_tick_ns = now_ns

    def text(self, who: str, watchdog_s: float | None) -> str:
        """The fault: the host stalled, so ``who`` (e.g. "ODrive node 0") went unfed and unread."""
        then = f"; the ODrive's watchdog idles the axis after {watchdog_s:g} s unfed" if watchdog_s else ""
        return (
            f"the host stalled for {self.stall_ns / 1e6:.0f} ms (this process got no CPU time: suspended or "
            f"overloaded), so {who} went unfed and unread{then}"
        )


def idle_not_confirmed(watchdog_s: float | None) -> str:
    """What the run says when the ODrive did not confirm its idle: what idles it then."""
    within = f"within {watchdog_s:g} s" if watchdog_s else "if its watchdog is enabled"
    return f"motor idle NOT confirmed; the ODrive watchdog idles it {within}"
