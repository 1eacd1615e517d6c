"""The limits the ODrive drivers (CAN and USB) send, checked on the host first: a ``vel_limit`` with a little
headroom over the protocol's highest frequency, never one that disables the limit, and a current limit within the
board's maximum."""

from __future__ import annotations

import math

from beambench.acquisition.capabilities import MotorLimits
from beambench.common.errors import BeambenchError

VEL_HEADROOM = 1.1  # vel_limit = max_frequency_hz × this
MAX_VEL_LIMIT = 250.0  # turn/s; never send more (the old script's 8000 disabled the limit)
MAX_CURRENT_LIMIT = 60.0  # A, the ODrive v3.6 hardware maximum


class LimitError(BeambenchError, ValueError):
    """A command or a limit outside what the protocol's limits allow; nothing was sent."""


def vel_limit_for(limits: MotorLimits) -> float:
    """The ``vel_limit`` (turn/s) sent for these limits; LimitError if unsafe or invalid."""
    f = limits.max_frequency_hz
    if not (math.isfinite(f) and f > 0):
        raise LimitError(f"max_frequency_hz = {f!r} must be a positive number")
    v = f * VEL_HEADROOM
    if v > MAX_VEL_LIMIT:
        raise LimitError(f"vel_limit {v:g} turn/s (max_frequency_hz {f:g} × {VEL_HEADROOM}) exceeds {MAX_VEL_LIMIT:g}")
    return v


def current_limit_for(limits: MotorLimits) -> float:
    a = limits.max_current_a
    if not (math.isfinite(a) and 0 < a <= MAX_CURRENT_LIMIT):
        raise LimitError(f"max_current_a = {a!r} must be in (0, {MAX_CURRENT_LIMIT:g}] A")
    return float(a)
