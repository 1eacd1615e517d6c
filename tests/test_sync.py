"""Clock fits, echo fits, resampling and the encoder↔marker delay against known truth."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.analysis.sync import (
    NS,
    ClockFit,
    encoder_marker_delay,
    fit_clock,
    fit_echo,
    fit_from_row,
    fits_table,
    resample,
    timeline,
)


def device_stream(rate_hz, duration_s, offset_s, drift_ppm, jitter_s, latency_s, rng, batch_s=None):
    """A device sampling at ``rate_hz`` on its own clock; returns (true host event time s, device s, host ns).

    Device clock: ``device = (t − offset)·(1 + drift)``. Host receives after ``latency + |N(0, jitter)|``;
    with ``batch_s`` the host stamps whole batches when it reads them (every ``batch_s``).
    """
    device = np.arange(0.0, duration_s, 1.0 / rate_hz) + rng.uniform(0, 1.0 / rate_hz)
    t = device / (1 + drift_ppm * 1e-6) + offset_s
    recv = t + latency_s + np.abs(rng.normal(0.0, jitter_s, len(t)))
    if batch_s:
        recv = (np.floor(recv / batch_s) + 1) * batch_s + rng.uniform(0, 2e-4, len(t)) * 0
    return t, device, np.round(recv * NS).astype(np.int64) + 10 * NS


@pytest.mark.parametrize("batch_s", [None, 0.1])
def test_mocap_and_loadcell_align_within_half_a_millisecond(batch_s):
    rng = np.random.default_rng(1)
    dur = 300.0
    _, d_m, h_m = device_stream(360.0, dur, 0.005, 50.0, 0.0004, 0.0005, rng, batch_s)
    _, d_l, h_l = device_stream(1000.0, dur, -0.012, -30.0, 0.0004, 0.0005, rng, batch_s)
    fm, fl = fit_clock(d_m, h_m, "mocap"), fit_clock(d_l, h_l, "loadcell")
    assert fm.drift_ppm == pytest.approx(50.0, abs=1.0)  # the device clock runs fast
    assert fl.drift_ppm == pytest.approx(-30.0, abs=1.0)
    # Events at the same true instant: where do the two fits put them on the host clock?
    probe = np.linspace(1.0, dur - 1.0, 2000)
    dev_m = (probe - 0.005) * (1 + 50e-6)
    dev_l = (probe + 0.012) * (1 - 30e-6)
    err_ms = (fm.to_host_ns(dev_m) - fl.to_host_ns(dev_l)) / 1e6
    assert np.max(np.abs(err_ms)) <= 0.5
    if batch_s is None:
        # unbatched: each fit lands within 0.1 ms of true time + latency
        true_ns = np.round((probe + 0.0005) * NS).astype(np.int64) + 10 * NS
        assert np.max(np.abs(fm.to_host_ns(dev_m) - true_ns)) < 1e5
        assert fm.residual_median_us == pytest.approx(0.4e3 * 0.674, rel=0.2)  # median of |N(0, 0.4 ms)|


def test_fit_is_a_lower_envelope_and_survives_glitches():
    rng = np.random.default_rng(2)
    _, d, h = device_stream(500.0, 60.0, 0.3, 80.0, 0.002, 0.001, rng)
    h = h.copy()
    h[[100, 5000, 20000]] -= 50_000_000  # three impossible early stamps (50 ms)
    f = fit_clock(d, h, "x")
    assert f.n_rejected == 3
    res = f.residuals_us(d, h)
    keep = np.ones(len(d), bool)
    keep[[100, 5000, 20000]] = False
    assert res[keep].min() == pytest.approx(0.0, abs=1e-3)  # touches the envelope, never above it
    assert f.drift_ppm == pytest.approx(80.0, abs=2.0)


def test_fit_degenerate_inputs():
    f = fit_clock(np.array([1.0]), np.array([5 * NS]), "one")
    assert f.method == "offset" and f.to_host_ns(1.0) == 5 * NS
    d = np.linspace(0, 10, 101)
    f = fit_clock(d, (d * NS).astype(np.int64) + 7, "exact")  # no jitter at all: collinear points
    assert np.all(np.abs(f.to_host_ns(d) - (d * NS + 7)) <= 1)
    with pytest.raises(ValueError):
        fit_clock(d, np.zeros(3, np.int64))


@pytest.mark.parametrize("host", ["constant", "backwards"])
def test_host_stamps_that_do_not_advance_are_no_clock_fit_and_no_division_by_zero(host):
    """An edited or broken session whose receive stamps stand still (or run back) while the device clock advances:
    a clock map with a rate <= 0 has no inverse (drift and offset divided by zero); it is a pure offset instead,
    and echo exchanges like it are refused."""
    d = np.linspace(0, 10, 101)
    h = np.full(101, 5 * NS, np.int64) if host == "constant" else (5 * NS - d * NS).astype(np.int64)
    with np.errstate(all="raise"):
        f = fit_clock(d, h, "still")
        assert f.method == "offset" and f.rate == 1.0
        assert np.isfinite(f.drift_ppm) and np.isfinite(f.offset_s)
        with pytest.raises(ValueError, match="do not advance"):
            fit_echo(h, h + 1000, d)


def test_fit_roundtrips_through_table():
    d = np.linspace(0, 100, 5001)
    h = np.round((d * (1 + 20e-6) + 3.0) * NS).astype(np.int64)
    f = fit_clock(d, h, "m")
    row = fits_table({"m": f}).iloc[0].to_dict()
    g = fit_from_row(row)
    assert np.array_equal(g.to_host_ns(d), f.to_host_ns(d))
    assert np.allclose(g.to_device(g.to_host_ns(d)), d, atol=1e-9)
    assert row["drift_ppm"] == pytest.approx(-20.0, abs=0.01)  # host = 1.00002·device: device slow


def test_echo_fit_uses_minimum_round_trips():
    rng = np.random.default_rng(3)
    n = 600
    send = np.sort(rng.uniform(0, 300, n))
    up = 80e-6 + rng.exponential(2e-3, n)  # queuing makes some legs slow
    down = 80e-6 + rng.exponential(2e-3, n)
    srv_true = send + up  # server stamps on arrival
    server = (srv_true - 0.005) * (1 + 50e-6)
    recv = srv_true + down
    f = fit_echo((send * NS).astype(np.int64), (recv * NS).astype(np.int64), server)
    probe = np.linspace(0, 300, 50)
    est = f.to_host_ns((probe - 0.005) * (1 + 50e-6))
    assert np.max(np.abs(est - probe * NS)) < 0.1e6  # within 0.1 ms
    assert f.extra["rtt_min_us"] < 400 and f.extra["bound_us"] < 1000
    # a naive fit on all midpoints is worse than the filtered one
    mid = (send + recv) / 2
    slope, icpt = np.polyfit(server, mid, 1)
    naive = (slope * (probe - 0.005) * (1 + 50e-6) + icpt) * NS
    assert np.max(np.abs(naive - probe * NS)) > np.max(np.abs(est - probe * NS))


def test_resample_leaves_raw_untouched_and_marks_gaps():
    t = np.arange(0, 1000) * 1_000_000  # 1 kHz
    v = np.stack([np.sin(t / 1e8), np.cos(t / 1e8)], axis=1)
    v[300:400, 0] = np.nan  # a dropout in one column only
    raw = v.copy()
    tgt = timeline(0, 1_000_000_000, 360.0)
    out = resample(t, v, tgt)
    assert np.array_equal(np.isnan(raw), np.isnan(v)) and np.allclose(np.nan_to_num(raw), np.nan_to_num(v))
    assert out.shape == (len(tgt), 2) and len(tgt) == 360
    gap = (tgt > 299e6) & (tgt < 400e6)
    assert np.all(np.isnan(out[gap, 0])) and np.all(np.isfinite(out[gap, 1]))
    good = ~gap & (tgt <= t[-1])
    assert np.allclose(out[good, 0], np.sin(tgt[good] / 1e8), atol=2e-5)
    assert np.isnan(resample(t, v, np.array([2_000_000_000]))[0, 1])  # outside the data


def test_encoder_marker_delay_recovers_known_lag():
    rng = np.random.default_rng(4)
    tau = 0.0062
    seg = []
    t0 = 0.0
    for f in (10.0, 15.0, 20.0, 25.0, 30.0):
        seg.append((t0, t0 + 2.0, f))
        t0 += 2.0
    mt = np.arange(0, t0, 0.01)  # motor telemetry at 100 Hz
    freq = np.zeros_like(mt)
    for a, b, f in seg:
        freq[(mt >= a) & (mt < b)] = f
    turns = np.concatenate([[0.0], np.cumsum(freq[:-1] * 0.01)])
    st = np.arange(0.2, t0 - 0.2, 1 / 360)
    # exact encoder angle at the delayed instants (linear between telemetry samples is exact here)
    ph = np.interp(st - tau, mt, turns)
    x = 0.002 * np.sin(2 * np.pi * ph + 0.7) + rng.normal(0, 20e-6, len(st))
    est = encoder_marker_delay((mt * NS).astype(np.int64), turns, (st * NS).astype(np.int64), x)
    assert est.delay_s == pytest.approx(tau, abs=0.2e-3)
    assert est.quality > 0.9
    # a single frequency cannot separate delay from crank phase
    one = encoder_marker_delay((mt * NS).astype(np.int64), mt * 20.0, (st * NS).astype(np.int64), x)
    assert np.isnan(one.delay_s)


def test_clockfit_inverse_and_offset():
    f = ClockFit("s", "hull", t0=10.0, host0_ns=5 * NS, rate=1.0001)
    assert f.offset_s == pytest.approx(10.0 - 5.0 / 1.0001)  # device reading at host time 0
    h = f.to_host_ns(np.array([10.0, 20.0]))
    assert h[0] == 5 * NS and h[1] == 5 * NS + round(10.0 * 1.0001 * NS)


def test_sim_device_clocks_over_five_minutes_align_within_half_a_millisecond():
    """The sim backend's own clock model (offset, drift, exponential receive jitter, FIFO link)."""
    from beambench.acquisition.protocol.schema import ClockModel
    from beambench.backends.sim_devices import DeviceClock

    rng = np.random.default_rng(9)
    mocap = DeviceClock(ClockModel(offset_s=0.005, drift_ppm=50.0, jitter_s=0.0004), 360.0, rng)
    cells = DeviceClock(ClockModel(offset_s=-0.002, drift_ppm=-20.0, jitter_s=0.0004), 1000.0, rng)
    fits = {}
    for name, clk in (("mocap", mocap), ("loadcell", cells)):
        k = np.arange(clk.k0, clk.last_index(300.0) + 1)
        d = k / clk.rate
        t = np.asarray(clk.true_time(d), float)
        fits[name] = fit_clock(d, clk.host_ns(t), name)
    probe = np.linspace(0.5, 299.5, 3000)
    err_ms = (
        fits["mocap"].to_host_ns(mocap.device_time(probe)) - fits["loadcell"].to_host_ns(cells.device_time(probe))
    ) / 1e6
    assert np.max(np.abs(err_ms)) <= 0.5
    assert fits["mocap"].drift_ppm == pytest.approx(50.0, abs=0.5)
    assert fits["mocap"].offset_s == pytest.approx(0.005 - 0.0005, abs=2e-5)  # offset − latency


def test_sync_edge_check_sees_a_misaligned_mocap_clock():
    from beambench.analysis.sync import sync_edge_check

    t_l = np.arange(0, 20, 1e-3)  # load-cell samples (true s)
    t_m = np.arange(0.0004, 20, 1 / 360)  # mocap exposures
    frames = np.arange(len(t_m)) + 5000  # Motive's frame numbers start anywhere
    edges = np.searchsorted(t_m, t_l, side="right")  # exposures seen so far, counted by the MCU from 0

    def ns(s):
        return np.round(s * NS).astype(np.int64)

    good = sync_edge_check(ns(t_l), edges, ns(t_m), frames)
    assert good.frame_offset == 1 - 5000
    assert good.p05_s >= 0.0 and good.p95_s < 1e-3 and good.n > 7000
    # mocap mapped 1 ms late (the check resolves errors below half a frame period; whole frames alias)
    late = sync_edge_check(ns(t_l), edges, ns(t_m + 0.001), frames)
    assert late.median_s == pytest.approx(good.median_s - 0.001, abs=1e-4)
    assert sync_edge_check(ns(t_l), np.zeros(len(t_l), np.int64), ns(t_m), frames) is None


def test_a_damaged_device_stamp_keeps_its_receive_time_and_the_rest_follow_the_fit():
    from types import SimpleNamespace

    from beambench.analysis.session_analysis import stream_host_times

    fit = ClockFit("s", "lower_envelope", t0=10.0, host0_ns=5_000_000_000, rate=1.0 + 20e-6)
    device = np.array([10.0, 10.5, np.nan, 11.0, 1e300, -np.inf])
    host = np.array([5_000_100_000, 5_500_120_000, 5_600_000_000, 6_000_150_000, 6_100_000_000, 6_200_000_000])
    assert fit.placeable(device).tolist() == [True, True, False, True, False, False]
    with np.errstate(all="raise"):  # no invalid cast on the way
        got = stream_host_times(SimpleNamespace(device_time=device, host_time_ns=host), fit)
    ok = [0, 1, 3]
    assert (got[ok] == fit.to_host_ns(device[ok])).all()
    assert (got[[2, 4, 5]] == host[[2, 4, 5]]).all()
