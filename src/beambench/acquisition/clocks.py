"""The one model of a device clock against true (host) time, used by the simulated devices, the emulators
(Motive's QPC counter, the load-cell MCU's microsecond clock) and, through ``from_model``, the protocol's
``sim.clocks`` settings (:class:`beambench.acquisition.protocol.schema.ClockModel`), and those settings by stream
name (:class:`DeviceClocks`).

A device clock runs ``drift_ppm`` fast and started ``offset_s`` ahead: ``device = offset_s + (1 + drift)·true``
with ``drift = drift_ppm·1e-6``. A device that samples every ``1/rate`` of *its* seconds therefore delivers
``rate·(1 + drift)`` samples per true second.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import overload

import numpy as np

from beambench.acquisition.protocol.schema import ClockModel

__all__ = ["DeviceClocks", "DriftingClock"]


@dataclass(frozen=True)
class DriftingClock:
    """``device = offset_s + (1 + drift_ppm·1e-6)·true`` (seconds)."""

    offset_s: float = 0.0
    drift_ppm: float = 0.0

    @property
    def scale(self) -> float:
        """Device seconds per true second."""
        return 1.0 + self.drift_ppm * 1e-6

    @overload
    def device_time(self, true_s: float) -> float: ...
    @overload
    def device_time(self, true_s: np.ndarray) -> np.ndarray: ...
    @overload
    def device_time(self, true_s: float | np.ndarray) -> float | np.ndarray: ...
    def device_time(self, true_s: float | np.ndarray) -> float | np.ndarray:
        return self.offset_s + self.scale * true_s

    @overload
    def true_time(self, device_s: float) -> float: ...
    @overload
    def true_time(self, device_s: np.ndarray) -> np.ndarray: ...
    @overload
    def true_time(self, device_s: float | np.ndarray) -> float | np.ndarray: ...
    def true_time(self, device_s: float | np.ndarray) -> float | np.ndarray:
        return (device_s - self.offset_s) / self.scale

    def rate_on_host(self, nominal_hz: float) -> float:
        """Samples per true second of a device sampling at ``nominal_hz`` on this clock."""
        return nominal_hz * self.scale

    @classmethod
    def from_model(cls, model: ClockModel) -> DriftingClock:
        """From the protocol's clock model (``sim.clocks.<stream>``)."""
        return cls(model.offset_s, model.drift_ppm)


@dataclass(frozen=True)
class DeviceClocks:
    """The simulated devices' clocks (offset, drift, jitter, latency) by stream name; a stream not named has the
    default clock."""

    named: tuple[tuple[str, ClockModel], ...] = ()

    @classmethod
    def of_mapping(cls, clocks: Mapping[str, ClockModel]) -> DeviceClocks:
        return cls(tuple(sorted(clocks.items())))

    def of(self, stream: str) -> ClockModel:
        """The clock of the stream named ``stream``."""
        return dict(self.named).get(stream, ClockModel())
