"""The motor telemetry stream over a row buffer, shared by the ODrive drivers (CAN and USB)."""

from __future__ import annotations

import time
from collections import deque
from typing import Any

import numpy as np

from beambench.acquisition.batch import Batch, StreamSpec
from beambench.acquisition.streams import MOTOR, motor_spec

MAX_BUFFERED_ROWS = 200_000  # ~33 min of telemetry if nobody reads


def rows_to_batch(rows: list[tuple]) -> Batch:
    """A motor Batch from rows (host_ns, device_t, position, velocity, setpoint, iq, vbus, state, error)."""
    if not rows:
        return motor_spec().empty_batch()
    host, dev, pos, vel, sp, iq, vbus, state, err = zip(*rows)
    cols: dict[str, np.ndarray] = {
        "position": np.asarray(pos, np.float64),
        "velocity": np.asarray(vel, np.float64),
        "velocity_setpoint": np.asarray(sp, np.float64),
        "iq_measured": np.asarray(iq, np.float64),
        "bus_voltage": np.asarray(vbus, np.float64),
        "axis_state": np.asarray(state, np.int32),
        "axis_error": np.asarray(err, np.int64),
    }
    return Batch(MOTOR, np.asarray(host, np.int64), np.asarray(dev, np.float64), cols)


class TelemetryStream:
    """The Motor's telemetry as a Stream over a row buffer, shared by the CAN and USB drivers: a driver
    appends rows (see :func:`rows_to_batch`) to ``_rows`` under ``_guard`` while ``_streaming``."""

    _guard: Any  # the driver's lock (or condition) that guards _rows and _streaming
    _rows: deque[tuple]
    _streaming: bool
    _streaming_ns: int | None
    open: Any  # the driver's own: connects if needed
    rows_received = 0  # telemetry rows buffered while streaming
    rows_evicted = 0  # of those, rows a full buffer dropped before anyone read them: lost

    def _buffer(self, row: tuple) -> None:
        """Buffer one telemetry row (the caller holds ``_guard``): a full buffer evicts its oldest row, counted."""
        self.rows_received += 1
        if len(self._rows) == self._rows.maxlen:
            self.rows_evicted += 1
        self._rows.append(row)

    def describe(self) -> StreamSpec:
        return motor_spec()

    def start(self) -> None:
        self.open()
        with self._guard:
            self._streaming = True
            self._streaming_ns = time.monotonic_ns()

    def stop(self) -> None:
        with self._guard:
            self._streaming = False

    def read(self) -> Batch:
        with self._guard:
            rows = list(self._rows)
            self._rows.clear()
        return rows_to_batch(rows)
