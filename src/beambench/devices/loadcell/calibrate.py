"""The load-cell plate's calibration procedure: tare, known loads, least-squares 2×4 matrix, residuals.

:func:`walkthrough` is independent of the terminal: it takes a running load-cell
:class:`~beambench.acquisition.capabilities.Stream`, the loads, an ``ask`` callable (a prompt that returns the answer)
and an optional ``on_step`` hook called when a load should be on the plate, and prints its tables on a rich
console. ``beambench calibrate loadcells`` (:mod:`beambench.commands.calibrate`) wires it to prompts on stdin, and
with ``--emulate`` to an emulated MCU on a pty whose force follows the steps (:func:`emulated_plate`). The
arithmetic (tare, fit, the saved file) is :mod:`beambench.acquisition.forces.loadcell_calibration`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np
    from rich.console import Console

    from beambench.acquisition.capabilities import Stream
    from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration, MatrixFit

EMULATE_LOADS = [(1.0, 0.0), (2.0, 0.0), (0.0, 0.5), (0.0, 1.0), (1.5, 0.5), (1.0, -0.5)]


class CalibrationAborted(Exception):
    """The walkthrough cannot go on (no samples, no answer); the message is one line for the user."""


@dataclass
class Recording:
    """Samples recorded for one step: their per-channel mean and standard deviation."""

    samples: np.ndarray

    @property
    def mean(self) -> np.ndarray:
        return self.samples.mean(axis=0)

    @property
    def std(self) -> np.ndarray:
        return self.samples.std(axis=0)


def parse_loads(values: list[str]) -> list[tuple[float, float]]:
    """``["1,0", "0,0.5 2,0"]`` → ``[(1, 0), (0, 0.5), (2, 0)]``; ValueError naming the bad one."""
    loads = []
    for value in values:
        for item in value.replace(";", " ").split():
            parts = item.split(",")
            try:
                if len(parts) != 2:
                    raise ValueError
                fn, ft = float(parts[0]), float(parts[1])
                if not (math.isfinite(fn) and math.isfinite(ft)):
                    raise ValueError
                loads.append((fn, ft))
            except ValueError:
                raise ValueError(f"--loads {item!r}: expected FN,FT in newtons (finite numbers), e.g. 1.0,0") from None
    return loads


def _noise_floor(std: np.ndarray) -> float:
    """Noise level used to tell a load from no load: the largest channel std, at least one count."""
    return max(float(std.max()), 1.0)


NO_SAMPLES_S = 5.0  # how long past its window a recording waits for a late (or a starved host's) first sample
WINDOW_TRIES = 3  # windows recorded in turn while the plate streams but one comes back empty (frames lost in a stall)


def record(stream: Stream, settle_s: float, duration_s: float, from_seq: int | None = None) -> Recording:
    """The samples of the ``duration_s`` window that starts ``settle_s`` after now (the user's Enter).

    Each frame is placed on the host's clock by the MCU's own stamp plus the least-delayed host-minus-MCU offset
    seen, so frames still in transit at the Enter (a host that reads late) count as before it, whenever read.
    A plate that streams but whose frames of the window were lost (a host or link stall that overflowed the MCU's
    transmit buffer) is recorded again, right after, up to ``WINDOW_TRIES`` windows: the load is on and settled.
    ``from_seq``: the first MCU frame (sequence number) that carries the step's load, when it is known (the
    emulated plate): the settle and the window are then counted in the MCU's own frames."""
    if from_seq is not None:
        return _record_frames(stream, settle_s, duration_s, from_seq)
    for _ in range(WINDOW_TRIES):
        rec = _record_window(stream, settle_s, duration_s)
        if rec is not None:
            return rec
        settle_s = 0.0
    raise CalibrationAborted(
        f"no load-cell samples in {WINDOW_TRIES} windows of {duration_s:g} s while the plate streamed: frames are "
        "lost (a busy host or USB link?); close other programs or record longer (--duration)"
    )


def _record_window(stream: Stream, settle_s: float, duration_s: float) -> Recording | None:
    """One host-clock window; None when the plate streamed but no frame of the window arrived."""
    import numpy as np

    from beambench.acquisition.batch import Batch

    start_ns = time.monotonic_ns() + round(settle_s * 1e9)
    end_ns = start_ns + round(duration_s * 1e9)
    batches: list[Batch] = []
    offset_ns = np.inf  # the least-delayed host-minus-MCU offset so far
    deadline = time.monotonic() + settle_s + duration_s + NO_SAMPLES_S
    while time.monotonic() < deadline:
        time.sleep(0.02)
        b = stream.read()
        if len(b):
            batches.append(b)
            dev = np.asarray(b.device_time) * 1e9
            offset_ns = min(offset_ns, float(np.min(b.host_time_ns - dev)))
            if dev[-1] + offset_ns >= end_ns:
                break
    if not batches:
        waited = settle_s + duration_s + NO_SAMPLES_S
        raise CalibrationAborted(f"no load-cell samples in {waited:g} s: is the MCU connected and running?")
    b = Batch.concat(batches)
    on_host = np.asarray(b.device_time) * 1e9 + offset_ns
    keep = (on_host >= start_ns) & (on_host < end_ns)
    if not np.any(keep):
        return None
    return Recording(np.asarray(b.columns["data"], dtype=np.float64)[keep])


def _record_frames(stream: Stream, settle_s: float, duration_s: float, from_seq: int) -> Recording:
    """Frames ``from_seq + settle`` … ``+ duration`` (counted at the stream's rate), however late they arrive."""
    import numpy as np

    rate = stream.describe().rate_hz
    first = from_seq + round(settle_s * rate)
    end = first + max(1, round(duration_s * rate))
    rows: list[np.ndarray] = []
    deadline = time.monotonic() + settle_s + duration_s + NO_SAMPLES_S
    last = first - 1
    while last < end - 1 and time.monotonic() < deadline:
        time.sleep(0.01)
        b = stream.read()
        if len(b):
            seq = np.asarray(b.columns["seq"])
            rows.append(np.asarray(b.columns["data"])[(seq >= first) & (seq < end)])
            last = max(last, int(seq.max()))
    samples = np.concatenate(rows) if rows else np.zeros((0, 4))
    if len(samples) == 0:
        waited = settle_s + duration_s + NO_SAMPLES_S
        raise CalibrationAborted(f"no load-cell samples in {waited:g} s: is the MCU connected and running?")
    return Recording(samples.astype(np.float64))


def walkthrough(
    stream: Stream,
    loads: list[tuple[float, float]] | None,
    ask: Callable[[str], str],
    console: Console,
    *,
    settle_s: float = 0.5,
    duration_s: float = 1.0,
    gain: np.ndarray | None = None,
    on_step: Callable[[tuple[float, float]], int | None] | None = None,
    source: str = "",
) -> tuple[LoadCellCalibration, MatrixFit]:
    """Tare then known loads, fitted. ``loads=None`` asks the user for each load until a blank answer."""
    import numpy as np
    from rich.table import Table

    from beambench.acquisition.forces.loadcell_calibration import (
        LoadCellCalibration,
        fit_matrix,
        tare_counts,
    )
    from beambench.acquisition.streams import LOADCELL_CHANNELS

    hook = on_step or (lambda load: None)
    from_seq = hook((0.0, 0.0))
    ask("Remove every load from the plate, then press Enter to record the tare")
    rec = record(stream, settle_s, duration_s, from_seq)
    tare = tare_counts(rec.samples)
    tare_std = rec.std
    t = Table(title=f"Tare ({len(rec.samples)} samples, mean over time per channel)")
    for col in ("", *LOADCELL_CHANNELS):
        t.add_column(col, justify="right")
    t.add_row("mean [count]", *(f"{v:.1f}" for v in tare))
    t.add_row("std [count]", *(f"{v:.1f}" for v in rec.std))
    console.print(t)

    known: list[tuple[float, float]] = []
    means: list[np.ndarray] = []
    k = 0
    while loads is None or k < len(loads):
        if loads is None:
            answer = ask(f"Known load {k + 1} as FN,FT in N (blank to finish)").strip()
            if not answer:
                break
            try:
                parsed = parse_loads([answer])
                if len(parsed) != 1:
                    raise ValueError(f"{answer!r}: one load at a time, as FN,FT")
            except ValueError as exc:
                console.print(f"[red]{exc}[/red]", soft_wrap=True)
                continue
            load = parsed[0]
        else:
            load = loads[k]
        from_seq = hook(load)
        ask(f"Apply load {k + 1}: Fn = {load[0]:g} N, Ft = {load[1]:g} N, then press Enter")
        rec = record(stream, settle_s, duration_s, from_seq)
        known.append(load)
        means.append(rec.mean)
        console.print(f"  load {k + 1}: {len(rec.samples)} samples, std {np.array2string(rec.std, precision=1)} counts")
        k += 1
    hook((0.0, 0.0))
    change = np.abs(np.array(means).reshape(-1, 4) - tare).max(initial=0.0)
    if known and change < 5 * _noise_floor(tare_std):
        raise CalibrationAborted(
            f"the loads changed the counts by at most {change:.0f}, within the noise ({tare_std.max():.0f} std): "
            "are the load cells connected and the weights on the plate?"
        )
    try:
        fit = fit_matrix(np.array(means).reshape(-1, 4), np.array(known).reshape(-1, 2), tare, gain)
    except ValueError as exc:
        raise CalibrationAborted(str(exc)) from None
    g = np.ones(4) if gain is None else np.asarray(gain, float)
    cal = LoadCellCalibration(tare=tare, gain=g, matrix=fit.matrix, sensitivity=fit.sensitivity, source=source)
    show_fit(console, fit)
    return cal, fit


def show_fit(console: Console, fit: MatrixFit) -> None:
    from rich.table import Table

    t = Table(title="Known loads and the fit (N)")
    for col in ("#", "Fn", "Ft", "Fn fit", "Ft fit", "ΔFn", "ΔFt"):
        t.add_column(col, justify="right")
    for i, (f, g, r) in enumerate(zip(fit.loads, fit.fitted, fit.residuals)):
        t.add_row(str(i + 1), *(f"{v:.4f}" for v in (*f, *g, *r)))
    console.print(t)
    m = Table(title=f"Matrix N per count (rank {fit.rank} of 4)")
    for col in ("", "lc0", "lc1", "lc2", "lc3"):
        m.add_column(col, justify="right")
    for name, row in zip(("Fn", "Ft"), fit.matrix):
        m.add_row(name, *(f"{v:.4e}" for v in row))
    console.print(m)
    console.print(f"RMS residual: Fn {fit.rms[0]:.4f} N, Ft {fit.rms[1]:.4f} N")


def emulated_plate() -> LoadCellCalibration:
    """A plate that differs from the shipped calibration (gains off by a few %, crosstalk, other offsets)."""
    import numpy as np

    from beambench.acquisition.forces.loadcell_calibration import (
        LoadCellCalibration,
        default_calibration,
    )

    nominal = default_calibration()
    rng = np.random.default_rng(7)
    sens = nominal.sensitivity * (1 + 0.05 * rng.standard_normal((4, 1))) + 400.0 * rng.standard_normal((4, 2))
    tare = nominal.tare + rng.normal(0.0, 300.0, 4)
    return LoadCellCalibration(tare=tare, sensitivity=sens, source="emulated plate")
