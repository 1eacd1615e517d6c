"""The settings every simulated run shares, travelling as one value instead of loose arguments.

A scene, a sweep or a calibration receives a :class:`SimSettings` (how long to settle and record, the beam's
twist, the drive amplitude, the integrator and timestep, noise and seed, threads) and passes it on whole;
a caller changes one field with :meth:`SimSettings.replace`. Frozen and made of plain values, so it pickles
to worker processes and hashes into an evaluation key.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class SimSettings:
    """One simulated run's window and numerics (SI units: s, deg, m)."""

    settle_s: float = 1.0
    """Time held at each frequency before recording (transients)."""
    record_s: float = 1.0
    """Recording window per frequency."""
    twist_deg: float = 90.0
    """The beam's pre-twist φ."""
    amplitude_m: float = 0.002
    """Stage amplitude A in x = A·sin(2πft)."""
    integrator: str | None = None
    """MuJoCo integrator name (``implicitfast``, ``euler``, …); ``None``: the model's own choice."""
    timestep: float | tuple[float, ...] | None = None
    """One timestep, one per frequency, or ``None``: chosen from the measured tables."""
    noise: bool = False
    """Sensor noise as the sim backend's devices add it."""
    seed: int = 0
    """Noise seed."""
    nthread: int | None = None
    """Threads for batched runs; ``None``: all cores."""

    def replace(self, **changes: Any) -> SimSettings:
        """A copy with ``changes`` applied (field names as above)."""
        return dataclasses.replace(self, **changes)
