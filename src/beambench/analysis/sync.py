"""One clock for every stream: device→host clock fits, resampling onto a common timeline, delay checks.

Every sample carries two stamps: the device's own clock (``device_time``, seconds) and the host's monotonic
receive time (``host_time_ns``). Receive delays are one-sided (a sample can arrive late, never early), so the
device→host map ``host = host0 + rate·(device − t0)`` is fitted to the *lower envelope* of the (device, host)
points: the line that lies below every point and is closest to them on average, i.e. the linear programme of
Moon, Skelly & Towsley (1999), solved exactly as the edge of the lower convex hull above the mean device time.
A constant transport latency common to all samples cannot be seen in one-way stamps; it ends up in the offset
(equal latencies cancel when streams are aligned with each other). For NatNet, the ECHO exchange measures it:
:func:`fit_echo` keeps the exchanges with the smallest round trip and fits the server clock to their midpoints.

All functions are pure (numpy in, numpy/dataclasses out); nothing here reads files.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import pandas as pd

NS = 1_000_000_000


def _placeable(offset_ns: np.ndarray) -> np.ndarray:
    """Offsets (float ns) that fit the int64 host clock: finite and within ±2^62 ns."""
    return np.isfinite(offset_ns) & (np.abs(offset_ns) < 2.0**62)


@dataclass(frozen=True)
class ClockFit:
    """A device→host clock map: ``host_ns = host0_ns + rate · (device_s − t0) · 1e9``.

    ``rate`` is host seconds per device second. In the convention of the sim's clock model
    (``device = offset + (1 + drift)·host``): ``drift_ppm`` is how fast the device clock runs (+50 = gains
    50 µs per second) and ``offset_s`` is the device's reading when the host clock reads 0 (it includes the
    constant receive latency, which one-way stamps cannot separate). Residual statistics are the one-sided
    receive delays ``host − fit`` of the points used, in microseconds.
    """

    stream: str
    method: str
    t0: float
    host0_ns: int
    rate: float = 1.0
    n: int = 0
    n_used: int = 0
    residual_median_us: float = float("nan")
    residual_p95_us: float = float("nan")
    residual_max_us: float = float("nan")
    n_rejected: int = 0
    extra: dict[str, float] = field(default_factory=dict)

    @property
    def drift_ppm(self) -> float:
        """Device clock rate error vs the host, ppm (positive: the device clock runs fast)."""
        return (1.0 / self.rate - 1.0) * 1e6

    @property
    def offset_s(self) -> float:
        """The device clock's reading (s) when the host clock reads 0."""
        return self.t0 - self.host0_ns / NS / self.rate

    def to_host_ns(self, device_time: np.ndarray | float) -> np.ndarray:
        """Host time (int64 ns) of events stamped ``device_time`` (s) on the device clock."""
        return np.round(self._offset_ns(device_time)).astype(np.int64) + np.int64(self.host0_ns)

    def _offset_ns(self, device_time: np.ndarray | float) -> np.ndarray:
        """Host ns after ``host0_ns`` of device stamps, as floats (a damaged stamp gives NaN or inf)."""
        return (np.asarray(device_time, dtype=np.float64) - self.t0) * (self.rate * NS)

    def placeable(self, device_time: np.ndarray) -> np.ndarray:
        """Which device stamps this map puts on the int64 host clock (finite, and within ±2^62 ns of ``host0_ns``):
        a damaged stamp (NaN, 1e300) is not one."""
        with np.errstate(invalid="ignore", over="ignore"):
            return _placeable(self._offset_ns(device_time))

    def host_times(self, device_time: np.ndarray, host_time_ns: np.ndarray) -> np.ndarray:
        """Host times (int64 ns) of samples stamped ``device_time`` and received at ``host_time_ns``: the map's,
        except for a stamp it cannot place (:meth:`placeable`), which keeps its receive time."""
        with np.errstate(invalid="ignore", over="ignore"):
            offset = self._offset_ns(device_time)
            ok = _placeable(offset)
        mapped = np.round(np.where(ok, offset, 0.0)).astype(np.int64) + np.int64(self.host0_ns)
        return np.where(ok, mapped, np.asarray(host_time_ns, np.int64))

    def to_device(self, host_time_ns: np.ndarray | int) -> np.ndarray:
        """Inverse map: device time (s) for host times (ns)."""
        h = np.asarray(host_time_ns, dtype=np.int64) - np.int64(self.host0_ns)
        return self.t0 + h.astype(np.float64) / (self.rate * NS)

    def residuals_us(self, device_time: np.ndarray, host_time_ns: np.ndarray) -> np.ndarray:
        """``host − fit`` in microseconds (receive delay relative to the fastest sample)."""
        return (np.asarray(host_time_ns, np.int64) - self.to_host_ns(device_time)).astype(np.float64) / 1e3

    def as_row(self) -> dict[str, object]:
        """A flat dict for tables (one row per stream)."""
        row = {k: v for k, v in asdict(self).items() if k != "extra"}
        row["drift_ppm"] = self.drift_ppm
        row["offset_s"] = self.offset_s
        row.update(self.extra)
        return row

    @staticmethod
    def identity(stream: str, host_time_ns: np.ndarray, device_time: np.ndarray) -> ClockFit:
        """Fallback when a stream cannot be fitted: a pure offset from the first sample."""
        if len(host_time_ns) == 0:
            return ClockFit(stream, "none", 0.0, 0)
        return ClockFit(stream, "offset", float(device_time[0]), int(host_time_ns[0]), 1.0, len(host_time_ns), 1)


def _lower_hull(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Indices of the lower convex hull of points sorted by x (monotone chain on a thinned candidate set)."""
    # Thin first: within each of ~2000 x-bins only the lowest point (relative to the chord) can matter for
    # a well-conditioned envelope, but hull vertices can be any point, so keep bin minima *and* bin ends.
    n = len(x)
    if n <= 4096:
        cand = np.arange(n)
    else:
        nb = 2048
        edges = np.linspace(0, n, nb + 1).astype(int)
        mins = [lo + int(np.argmin(y[lo:hi])) for lo, hi in itertools.pairwise(edges) if hi > lo]
        cand = np.unique(np.concatenate([np.asarray(mins), [0, n - 1]]))
        # Any point below the piecewise-linear chain through the bin minima could still be a hull vertex.
        chain = np.interp(x, x[cand], y[cand])
        below = np.flatnonzero(y < chain - 1e-15)
        cand = np.unique(np.concatenate([cand, below]))
    hull: list[int] = []
    for i in cand:
        while len(hull) >= 2:
            a, b = hull[-2], hull[-1]
            cross = (x[b] - x[a]) * (y[i] - y[a]) - (y[b] - y[a]) * (x[i] - x[a])
            if cross <= 0:  # b is not below the chord a→i
                hull.pop()
            else:
                break
        hull.append(int(i))
    return np.asarray(hull, dtype=int)


def _robust_prefit(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Line through per-bin minima with a Theil–Sen slope: a first guess immune to a few bad points.

    ``x`` must be sorted. (Theil–Sen by hand: importing ``scipy.stats`` costs seconds.)
    """
    nb = int(np.clip(len(x) // 8, 2, 64))
    edges = np.searchsorted(x, np.linspace(x[0], x[-1], nb + 1)[1:-1])
    bounds = np.concatenate([[0], edges, [len(x)]])
    xs, ys = [], []
    for lo, hi in itertools.pairwise(bounds):
        if hi > lo:
            j = lo + int(np.argmin(y[lo:hi]))
            xs.append(x[j])
            ys.append(y[j])
    if len(xs) < 2:
        return float(y[0]), 0.0
    xa, ya = np.asarray(xs), np.asarray(ys)
    i, j = np.triu_indices(len(xa), 1)
    dx = xa[j] - xa[i]
    good = dx > 0
    slope = float(np.median((ya[j] - ya[i])[good] / dx[good])) if good.any() else 0.0
    intercept = float(np.median(ya - slope * xa))
    return intercept, slope


def fit_clock(
    device_time: np.ndarray,
    host_time_ns: np.ndarray,
    stream: str = "",
    *,
    reject_below_us: float | None = None,
) -> ClockFit:
    """Fit the device→host clock map of one stream to the lower envelope of its receive stamps.

    Points far *below* a robust first guess (host clock steps, corrupt device stamps) are dropped before the
    envelope fit: below ``reject_below_us`` (default: 20× the spread of per-bin minima, at least 200 µs).
    Returns a :class:`ClockFit`; with fewer than 2 usable points, a pure offset.
    """
    d = np.asarray(device_time, dtype=np.float64)
    h = np.asarray(host_time_ns, dtype=np.int64)
    if d.shape != h.shape:
        raise ValueError(f"{stream}: device_time {d.shape} and host_time_ns {h.shape} differ")
    ok = np.isfinite(d)
    n = len(d)
    if ok.sum() < 2 or np.ptp(d[ok]) <= 0:
        return ClockFit.identity(stream, h[ok], d[ok])
    d, h = d[ok], h[ok]
    order = np.argsort(d, kind="stable")
    d, h = d[order], h[order]
    t0, h0 = float(d[0]), int(h[0])
    x = d - t0
    y = (h - h0).astype(np.float64) / NS - x  # residual vs a unit-rate clock, seconds; well conditioned

    a0, b0 = _robust_prefit(x, y)
    r0 = y - (a0 + b0 * x)
    if reject_below_us is None:
        spread = float(np.median(np.abs(r0 - np.median(r0))))
        thr = max(20.0 * spread, 200e-6)
    else:
        thr = reject_below_us * 1e-6
    keep = r0 >= -thr
    xk, yk = x[keep], y[keep]
    if len(xk) < 2 or np.ptp(xk) <= 0:
        return ClockFit.identity(stream, h, d)

    hull = _lower_hull(xk, yk)
    xm = float(np.mean(xk))
    if len(hull) < 2:
        slope, intercept = b0, a0
    else:
        k = int(np.clip(np.searchsorted(xk[hull], xm, side="right") - 1, 0, len(hull) - 2))
        i, j = hull[k], hull[k + 1]
        slope = (yk[j] - yk[i]) / (xk[j] - xk[i])
        intercept = yk[i] - slope * xk[i]
    if not 1.0 + slope > 0:  # host stamps that never advance (or run back) with the device's: no clock to fit
        return ClockFit.identity(stream, h, d)
    res = yk - (intercept + slope * xk)
    res_us = res * 1e6
    return ClockFit(
        stream,
        "hull",
        t0,
        h0 + round(float(intercept) * NS),
        1.0 + slope,
        n,
        int(keep.sum()),
        float(np.median(res_us)),
        float(np.percentile(res_us, 95)),
        float(np.max(res_us)),
        int((~keep).sum()),
    )


def fit_echo(
    client_send_ns: np.ndarray,
    client_recv_ns: np.ndarray,
    server_time_s: np.ndarray,
    stream: str = "mocap",
    *,
    bins: int = 10,
    keep_per_bin: int = 3,
) -> ClockFit:
    """Fit a server clock (s) to the host clock from request/response exchanges (NatNet ECHO).

    Each exchange gives the server's time at some instant between the client's send and receive; the
    midpoint is exact when the two legs are symmetric and off by at most RTT/2 otherwise. Queuing only ever
    lengthens the round trip, so the exchanges with the smallest RTT are kept (the fastest ``keep_per_bin``
    in each of ``bins`` time bins, which also lets drift be fitted over a long run) and a line is fitted to
    their midpoints by least squares. ``extra`` holds ``rtt_min_us``, ``rtt_median_us`` and ``bound_us``.
    """
    s = np.asarray(client_send_ns, np.int64)
    r = np.asarray(client_recv_ns, np.int64)
    srv = np.asarray(server_time_s, np.float64)
    if not (s.shape == r.shape == srv.shape):
        raise ValueError("client_send_ns, client_recv_ns and server_time_s must have the same length")
    ok = (r >= s) & np.isfinite(srv)
    s, r, srv = s[ok], r[ok], srv[ok]
    if len(s) == 0:
        raise ValueError("no valid echo exchanges (need recv >= send)")
    rtt = (r - s).astype(np.float64)
    h0 = int(s[0])
    mid = (s - h0).astype(np.float64) / NS + rtt / 2 / NS  # seconds since first send
    if len(s) >= bins * keep_per_bin and bins > 1:
        edges = np.linspace(srv.min(), srv.max(), bins + 1)
        idx = np.clip(np.searchsorted(edges, srv, side="right") - 1, 0, bins - 1)
        chosen: list[int] = []
        for b in range(bins):
            sel = np.flatnonzero(idx == b)
            chosen.extend(sel[np.argsort(rtt[sel])[:keep_per_bin]])
        use = np.asarray(sorted(chosen))
    else:
        use = np.argsort(rtt)[: max(1, len(rtt) // 4)]
    t0 = float(srv[use].min())
    x = srv[use] - t0
    if len(use) >= 2 and np.ptp(x) > 0:
        slope, intercept = np.polyfit(x, mid[use], 1)
    else:
        slope, intercept = 1.0, float(np.mean(mid[use] - x))
    if not slope > 0:
        raise ValueError("the echo exchanges' host times do not advance with the server's clock")
    res_us = (mid[use] - (intercept + slope * x)) * 1e6
    return ClockFit(
        stream,
        "echo",
        t0,
        h0 + round(float(intercept) * NS),
        float(slope),
        len(s),
        len(use),
        float(np.median(res_us)),
        float(np.percentile(np.abs(res_us), 95)),
        float(np.max(np.abs(res_us))),
        int((~ok).sum()),
        {
            "rtt_min_us": float(rtt.min() / 1e3),
            "rtt_median_us": float(np.median(rtt) / 1e3),
            "bound_us": float(rtt[use].max() / 2e3),
        },
    )


def fits_table(fits: dict[str, ClockFit] | list[ClockFit]) -> pd.DataFrame:
    """One row per stream: method, drift (ppm), offset (s), residual statistics (µs)."""
    items = list(fits.values()) if isinstance(fits, dict) else list(fits)
    return pd.DataFrame([f.as_row() for f in items])


def fit_from_row(row: Mapping[str, Any]) -> ClockFit:
    """Rebuild a :class:`ClockFit` from a :func:`fits_table` row (as stored in ``/processing``)."""
    base = {k: row[k] for k in ("stream", "method", "t0", "rate") if k in row}
    return ClockFit(**base, host0_ns=int(row["host0_ns"]))


# ---------------------------------------------------------------------------------------------- resampling


def timeline(start_ns: int, end_ns: int, rate_hz: float) -> np.ndarray:
    """A uniform host-clock timeline (int64 ns) from ``start_ns`` (inclusive) to ``end_ns`` (exclusive)."""
    step = NS / rate_hz
    n = max(0, int(np.floor((end_ns - start_ns) / step - 1e-9)) + 1)
    return start_ns + np.round(np.arange(n) * step).astype(np.int64)


def resample(
    t_ns: np.ndarray,
    values: np.ndarray,
    target_ns: np.ndarray,
    *,
    max_gap_s: float | None = None,
) -> np.ndarray:
    """Linear interpolation of ``values[n, ...]`` sampled at ``t_ns`` onto ``target_ns``; the input is untouched.

    Non-finite samples (occluded markers, dropouts) are skipped per column; a target point gets NaN when it
    lies outside the data or between two valid samples further apart than ``max_gap_s`` (default: 5 median
    sample intervals).
    """
    t = np.asarray(t_ns, np.int64)
    v = np.asarray(values, dtype=np.float64)
    tgt = np.asarray(target_ns, np.int64)
    out_shape = (len(tgt), *v.shape[1:])
    if len(t) == 0:
        return np.full(out_shape, np.nan)
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    if max_gap_s is None:
        dt = np.diff(t)
        max_gap_s = 5.0 * float(np.median(dt)) / NS if len(dt) else 0.0
    base = t[0]
    tf = (t - base).astype(np.float64)
    gf = (tgt - base).astype(np.float64)
    flat = v.reshape(len(t), -1)
    out = np.full((len(tgt), flat.shape[1]), np.nan)
    gap = max_gap_s * NS
    for c in range(flat.shape[1]):
        col = flat[:, c]
        ok = np.isfinite(col)
        if ok.sum() < 2:
            continue
        tv, cv = tf[ok], col[ok]
        res = np.interp(gf, tv, cv, left=np.nan, right=np.nan)
        j = np.clip(np.searchsorted(tv, gf, side="right"), 1, len(tv) - 1)
        span = tv[j] - tv[j - 1]
        exact = (gf == tv[j - 1]) | (gf == tv[j])
        res[(span > gap) & ~exact] = np.nan
        out[:, c] = res
    return out.reshape(out_shape)


def hold_previous(
    t_ns: np.ndarray, values: np.ndarray, target_ns: np.ndarray, *, max_gap_s: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The last sample at or before each target time (a zero-order hold), for discrete columns (states, counters,
    flags) that interpolation would turn into values never sent. Returns ``(values[target], valid)``, the values
    in their own dtype; ``valid`` is False before the first sample and where the last sample is older than
    ``max_gap_s`` (default: 5 median sample intervals)."""
    t = np.asarray(t_ns, np.int64)
    v = np.asarray(values)
    tgt = np.asarray(target_ns, np.int64)
    if len(t) == 0:
        return np.zeros((len(tgt), *v.shape[1:]), v.dtype), np.zeros(len(tgt), bool)
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    if max_gap_s is None:
        dt = np.diff(t)
        max_gap_s = 5.0 * float(np.median(dt)) / NS if len(dt) else 0.0
    i = np.searchsorted(t, tgt, side="right") - 1
    valid = i >= 0
    i = np.clip(i, 0, len(t) - 1)
    valid &= (tgt - t[i]) <= max_gap_s * NS
    return v[i], valid


# ---------------------------------------------------------------------------------- encoder ↔ marker delay


@dataclass(frozen=True)
class DelayEstimate:
    """Delay (s) of the stage marker behind the motor encoder; ``quality`` in [0, 1] (1 = perfect sine)."""

    delay_s: float
    quality: float
    n: int
    frequency_span_hz: float


def encoder_marker_delay(
    motor_t_ns: np.ndarray,
    motor_turns: np.ndarray,
    stage_t_ns: np.ndarray,
    stage_disp: np.ndarray,
    *,
    max_delay_s: float = 0.1,
) -> DelayEstimate:
    """Delay between the motor encoder and the stage marker by phasor cross-correlation.

    The crank makes the stage follow ``x = A·sin(2π·θ(t − τ) + φ)`` with θ the encoder angle in turns. For each
    trial delay τ the stage displacement is correlated with ``exp(−2πi·θ(t − τ))``; the magnitude peaks at the
    true τ. At one constant frequency τ and φ cannot be told apart, so the estimate needs several
    frequencies (a sweep): the phase then lines up across steps only at the true delay. Positive = the stage
    marker is seen later than the encoder predicts. NaN when the frequency span is too small.
    """
    mt = np.asarray(motor_t_ns, np.int64)
    th = np.asarray(motor_turns, np.float64)
    st = np.asarray(stage_t_ns, np.int64)
    s = np.asarray(stage_disp, np.float64)
    ok = np.isfinite(th)
    mt, th = mt[ok], th[ok]
    order = np.argsort(mt, kind="stable")
    mt, th = mt[order], th[order]
    first = np.concatenate([[True], np.diff(mt) > 0])  # drop repeated stamps
    mt, th = mt[first], th[first]
    ok = np.isfinite(s)
    st, s = st[ok], s[ok]
    if len(mt) < 4 or len(st) < 16:
        return DelayEstimate(float("nan"), 0.0, len(st), 0.0)
    base = mt[0]
    mtf = (mt - base).astype(np.float64) / NS
    stf = (st - base).astype(np.float64) / NS
    inside = (stf - max_delay_s >= mtf[0]) & (stf + max_delay_s <= mtf[-1])
    stf, s = stf[inside], s[inside]
    if len(s) < 16:
        return DelayEstimate(float("nan"), 0.0, len(s), 0.0)
    s = s - np.mean(s)
    vel = np.gradient(th, mtf)
    fspan = float(np.nanpercentile(np.abs(vel), 95) - np.nanpercentile(np.abs(vel), 5))

    def corr(tau: float, step: int = 1) -> float:
        ss = s[::step]
        ph = np.interp(stf[::step] - tau, mtf, th)
        return float(np.abs(np.sum(ss * np.exp(-2j * np.pi * ph)))) / float(np.sqrt(np.sum(ss**2) * len(ss) / 2.0))

    if fspan < 0.5:
        return DelayEstimate(float("nan"), corr(0.0), len(s), fspan)
    # the correlation peak is ~1/fspan wide: a coarse grid on a subsample, then a fine search on everything
    dstep = min(2.5e-3, 0.1 / fspan)
    grid = np.arange(-max_delay_s, max_delay_s + 1e-12, dstep)
    sub = max(1, len(s) // 20000)
    vals = np.array([corr(t, sub) for t in grid])
    k = int(np.argmax(vals))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    from scipy.optimize import minimize_scalar

    best = minimize_scalar(lambda t: -corr(t), bounds=(lo, hi), method="bounded", options={"xatol": 1e-6})
    return DelayEstimate(float(best.x), float(-best.fun), len(s), fspan)


# ------------------------------------------------------------------------- hardware sync-edge cross-check


@dataclass(frozen=True)
class EdgeCheck:
    """Load-cell sample that saw a mocap exposure pulse minus that mocap frame's time, on the host clock.

    With both clocks fitted this sits in [0, one load-cell sample period) (the pulse is seen by the next
    sample); a shift or a spread beyond that is a sync error. ``frame_offset``: edge count − frame number.
    """

    median_s: float
    p05_s: float
    p95_s: float
    n: int
    frame_offset: int


def sync_edge_check(
    loadcell_t_ns: np.ndarray,
    sync_edges: np.ndarray,
    mocap_t_ns: np.ndarray,
    mocap_frame: np.ndarray,
    *,
    search: int = 5,
) -> EdgeCheck | None:
    """Compare the times at which the load-cell MCU counted mocap exposure pulses with the mocap frame times.

    The MCU's counter and Motive's frame numbers start at different values; the integer offset between them
    is found as the one that makes the time differences smallest, so errors are seen modulo one frame period
    (below ±half a frame, 1.4 ms at 360 Hz). None when there are no edges or frames.
    """
    lt = np.asarray(loadcell_t_ns, np.int64)
    ed = np.asarray(sync_edges, np.int64)
    mt = np.asarray(mocap_t_ns, np.int64)
    fr = np.asarray(mocap_frame, np.int64)
    inc = np.flatnonzero(np.diff(ed) > 0) + 1
    if len(inc) < 3 or len(fr) < 3:
        return None
    counts, t_edge = ed[inc], lt[inc]
    order = np.argsort(fr, kind="stable")
    fr, mt = fr[order], mt[order]

    def diffs(offset: int) -> np.ndarray:
        want = counts - offset
        j = np.clip(np.searchsorted(fr, want), 0, len(fr) - 1)
        hit = fr[j] == want
        return (t_edge[hit] - mt[j[hit]]).astype(np.float64) / NS

    mid = len(inc) // 2
    near = int(np.argmin(np.abs(mt - t_edge[mid])))
    guess = int(counts[mid] - fr[near])
    best: tuple[float, int, np.ndarray] | None = None
    for off in range(guess - search, guess + search + 1):
        d = diffs(off)
        if len(d) < max(3, len(inc) // 4):
            continue
        score = float(np.median(np.abs(d)))
        if best is None or score < best[0]:
            best = (score, off, d)
    if best is None:
        return None
    _, off, d = best
    return EdgeCheck(float(np.median(d)), float(np.percentile(d, 5)), float(np.percentile(d, 95)), len(d), off)
