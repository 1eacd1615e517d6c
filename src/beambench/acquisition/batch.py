"""Batches of samples: the one unit of data that flows from devices to sinks.

A :class:`Batch` is the one unit of data that flows through beambench: a few hundred samples of one stream,
each stamped with the host's monotonic receive time (``host_time_ns``) and the device's own clock
(``device_time``, seconds). Devices describe their streams once with a :class:`StreamSpec`, so sinks
(HDF5, Rerun, monitors) need no per-device code.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class ColumnSpec:
    """One per-sample column: its per-sample shape, dtype, unit and (optional) labels of the last axis, and
    whether the live view plots it as a time series (``plotted``: one series per label, else one)."""

    shape: tuple[int, ...] = ()
    dtype: str = "float64"
    unit: str = ""
    labels: tuple[str, ...] = ()
    description: str = ""
    plotted: bool = False


@dataclass(frozen=True)
class Frame:
    """The world frame of a stream's positions: which (signed) axis is up, which is forward, and the unit.

    The sim streams z up; Motive (emulated and real) streams y up unless the lab calibrated it otherwise
    (``geometry`` in the rig file). Sinks draw and analysis reads positions in this frame.
    """

    up_axis: str = "z"
    forward_axis: str = "x"
    unit: str = "m"

    def as_dict(self) -> dict[str, str]:
        return {"up_axis": self.up_axis, "forward_axis": self.forward_axis}


@dataclass(frozen=True)
class StreamSpec:
    """What a stream produces: name, nominal rate and its columns (``data`` first by convention)."""

    name: str
    rate_hz: float
    columns: dict[str, ColumnSpec]
    device_time_unit: str = "s"
    description: str = ""
    frame: Frame | None = None  # the world frame of spatial streams (mocap); None for the others

    def empty_batch(self) -> Batch:
        """A batch with zero samples and the right column shapes."""
        cols = {k: np.zeros((0, *c.shape), dtype=c.dtype) for k, c in self.columns.items()}
        return Batch(self.name, np.zeros(0, np.int64), np.zeros(0, np.float64), cols)


@dataclass(frozen=True)
class Batch:
    """Samples of one stream: ``host_time_ns[n]``, ``device_time[n]`` and ``columns[name][n, ...]``."""

    stream: str
    host_time_ns: np.ndarray
    device_time: np.ndarray
    columns: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.host_time_ns)
        if len(self.device_time) != n:
            raise ValueError(f"{self.stream}: device_time has {len(self.device_time)} rows, expected {n}")
        for name, col in self.columns.items():
            if len(col) != n:
                raise ValueError(f"{self.stream}.{name}: {len(col)} rows, expected {n}")

    def __len__(self) -> int:
        return len(self.host_time_ns)

    @staticmethod
    def concat(batches: list[Batch]) -> Batch:
        """Join batches of the same stream in order."""
        if not batches:
            raise ValueError("no batches to join")
        first = batches[0]
        return Batch(
            first.stream,
            np.concatenate([b.host_time_ns for b in batches]),
            np.concatenate([b.device_time for b in batches]),
            {k: np.concatenate([b.columns[k] for b in batches]) for k in first.columns},
        )


@dataclass
class StepRecord:
    """One protocol step as the sinks see it (a row of ``/steps``); ``status``: running, done, aborted, fault."""

    index: int
    frequency_hz: float
    t_start_ns: int
    t_settled_ns: int = -1
    t_end_ns: int = -1
    status: str = "running"
    direction: str = "up"  # the sweep branch: up or down
    kind: str = "sweep"  # sweep or reference
    repeat: int = 0  # which pass of this frequency and branch (reference steps: the reference's count)
