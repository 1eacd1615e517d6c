"""Synthetic sessions with a known truth, written through the real :class:`~beambench.sinks.session_file.writer.SessionWriter`.

Used by the analysis tests and benchmark (and handy in notebooks): every number the analysis should recover
— drive frequency and amplitude, the tip ellipse (axes, tilt, sense), contacts every k-th cycle, the direction
of the foot at touchdown, the tangential force sign, a walker's body speed, clock offsets and drift — is an
input here. World frame: x = drive axis, z = up, plate at z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from beambench.acquisition.batch import Batch
from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration, default_calibration
from beambench.acquisition.protocol.scenes import scene_info
from beambench.acquisition.streams import (
    CONTACT_MARKERS,
    WALKER_MARKERS,
    loadcell_spec,
    mocap_spec,
    motor_spec,
)

NS = 1_000_000_000


@dataclass(frozen=True)
class SynthStep:
    """One step's truth. ``contact_every``: a touchdown every k-th drive cycle (0 = never, -1 = always on)."""

    frequency_hz: float
    contact_every: int = 1
    major_mm: float = 3.0
    minor_mm: float = 1.0
    tilt_deg: float = 20.0
    clockwise: bool = True
    touchdown_velocity_sign: int = 1
    tangential_n: float = 0.2
    body_speed_mm_s: float = 0.0
    direction: str = "up"  # as recorded in /steps
    kind: str = "sweep"
    repeat: int = 0


@dataclass(frozen=True)
class SynthClock:
    """As ``beambench.acquisition.protocol.schema.ClockModel``: device = offset + (1 + drift)·t; receive = t + latency + |N(0, jitter)|."""

    offset_s: float = 0.0
    drift_ppm: float = 0.0
    jitter_s: float = 0.0002
    latency_s: float = 0.0005


@dataclass
class SynthSession:
    """Settings of a synthetic session (rates follow ``beambench.acquisition.streams``)."""

    steps: list[SynthStep]
    rig: str = "contact"
    settle_s: float = 0.5
    record_s: float = 2.0
    amplitude_mm: float = 2.0
    mocap_noise_m: float = 20e-6
    force_noise_n: float = 0.005
    peak_normal_n: float = 1.5
    mocap_dropout: float = 0.0  # share of frames missing entirely
    occlusion: float = 0.0  # share of (frame, marker) occluded
    lift_mm: float = 0.3
    encoder_delay_s: float = 0.0
    clocks: dict[str, SynthClock] = field(default_factory=dict)
    calibration: LoadCellCalibration | None = None
    seed: int = 0
    batch_s: float = 0.5
    natnet_echo: bool = False  # store ECHO exchanges with Motive (QPC clock = the mocap device clock)
    interrupted_in: int | None = None  # a SIGINT half-way through this step's record window: it is cut short
    # ("aborted"), the later steps never run and the last event is the runner's "interrupted"


def _schedule(cfg: SynthSession) -> list[tuple[float, float, float]]:
    """(t_start, t_settled, t_end) of each step in true seconds from 1 s."""
    out, t = [], 1.0
    for _ in cfg.steps:
        out.append((t, t + cfg.settle_s, t + cfg.settle_s + cfg.record_s))
        t += cfg.settle_s + cfg.record_s
    return out


def _truth_at(cfg: SynthSession, sched: list[tuple[float, float, float]], t: np.ndarray) -> np.ndarray:
    """Index of the step active at each true time (−1 before the first)."""
    starts = np.array([s[0] for s in sched])
    return np.searchsorted(starts, t, side="right") - 1


def _crank_turns(cfg: SynthSession, sched: list[tuple[float, float, float]], t: np.ndarray) -> np.ndarray:
    """Cumulative crank angle (turns): frequency steps at each step start."""
    out = np.zeros_like(t)
    acc = 0.0
    edges = [s[0] for s in sched] + [np.inf]
    for i, st in enumerate(cfg.steps):
        a, b = edges[i], edges[i + 1]
        sel = (t >= a) & (t < b)
        out[sel] = acc + st.frequency_hz * (t[sel] - a)
        if np.isfinite(b):
            acc += st.frequency_hz * (b - a)
    return out


def _step_turns(cfg: SynthSession, sched, turns: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Crank turns since the start of the active step (``turns`` before the first step)."""
    starts = _crank_turns(cfg, sched, np.array([s[0] for s in sched]))
    return turns - np.where(idx >= 0, starts[np.clip(idx, 0, None)], 0.0)


def _contact_state(cfg: SynthSession, sched, t: np.ndarray, turns: np.ndarray):
    """Normal force, tangential force, foot lift (m) and foot tangential velocity sign at each true time."""
    idx = _truth_at(cfg, sched, t)
    fn = np.zeros_like(t)
    ft = np.zeros_like(t)
    lift = np.zeros_like(t)
    for i, st in enumerate(cfg.steps):
        sel = idx == i
        if not sel.any():
            continue
        k = st.contact_every
        if k == 0:
            lift[sel] = cfg.lift_mm * 1e-3 * (1 + np.sin(2 * np.pi * turns[sel])) / 2 + 0.5e-3
            continue
        if k < 0:
            fn[sel] = cfg.peak_normal_n * (0.6 + 0.4 * np.sin(2 * np.pi * turns[sel]))
            ft[sel] = st.tangential_n
            continue
        # contact during phase [0, 0.3) of every k-th cycle, counted from the step start
        local = _step_turns(cfg, sched, turns, idx)[sel]
        cyc = np.floor(local)
        ph = local - cyc
        on = (cyc % k == 0) & (ph < 0.3)
        pulse = np.where(on, np.sin(np.pi * ph / 0.3), 0.0)
        fn[sel] = cfg.peak_normal_n * pulse
        ft[sel] = np.where(on, st.tangential_n * pulse, 0.0)
        # foot height: off the plate between contacts, a smooth hump over the flight
        span = (cyc % k + ph - 0.3) / (k - 0.3)
        lift[sel] = np.where(on, 0.0, cfg.lift_mm * 1e-3 * np.sin(np.pi * np.clip(span, 0, 1)))
    return fn, ft, lift, idx


def markers(cfg: SynthSession, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Marker positions (n, M, 3) at true times ``t``: contact rig (stage, tip, foot) or walker (body, feet)."""
    sched = _schedule(cfg)
    turns = _crank_turns(cfg, sched, t - cfg.encoder_delay_s)
    stage_x = cfg.amplitude_mm * 1e-3 * np.sin(2 * np.pi * turns)
    idx = _truth_at(cfg, sched, t)
    n = len(t)
    # tip relative to the stage: the step's ellipse in (x = drive, z = up)
    ell = np.zeros((n, 2))
    vx_sign = np.ones(n)
    body_x = np.zeros(n)
    x_acc = 0.0
    for i, st in enumerate(cfg.steps):
        sel = idx == i
        if not sel.any():
            continue
        w = 2 * np.pi * turns[sel]
        s = -1.0 if st.clockwise else 1.0
        loc = np.stack([st.major_mm / 2 * np.cos(w), s * st.minor_mm / 2 * np.sin(w)])
        th = np.deg2rad(st.tilt_deg)
        rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        ell[sel] = (rot @ loc).T * 1e-3
        vx_sign[sel] = st.touchdown_velocity_sign
        body_x[sel] = x_acc + st.body_speed_mm_s * 1e-3 * (t[sel] - sched[i][0])
        x_acc += st.body_speed_mm_s * 1e-3 * (cfg.settle_s + cfg.record_s)
    if scene_info(cfg.rig).walks:
        body = np.stack(
            [body_x + 0.2e-3 * np.sin(2 * np.pi * turns), np.zeros(n), 0.03 + 0.3e-3 * np.cos(2 * np.pi * turns)], 1
        )
        left = body + np.stack([ell[:, 0], np.full(n, 0.05), ell[:, 1] - 0.03], 1)
        right = body + np.stack([ell[:, 0], np.full(n, -0.05), ell[:, 1] - 0.03], 1)
        pos = np.stack([body, left, right], 1)
    else:
        stage = np.stack([stage_x, np.zeros(n), np.full(n, 0.072)], 1)
        tip = stage + np.stack([ell[:, 0], np.full(n, 0.05), ell[:, 1]], 1)
        _, _, lift, _ = _contact_state(cfg, sched, t, turns)
        # foot: below the tip; touchdowns happen at cycle phase 0, where its x velocity (relative to the
        # plate) has the step's sign; its height is the lift above the plate
        # the phase counts from the step start, as the touchdowns do: a step starting at a non-integer turn
        # (12.5 turns into a 5 Hz first step) must not flip the velocity sign
        foot_x = 0.05 + 0.5e-3 * vx_sign * np.sin(2 * np.pi * _step_turns(cfg, sched, turns, idx))
        foot = np.stack([foot_x, np.full(n, 0.05), lift], 1)
        pos = np.stack([stage, tip, foot], 1)
    return pos + rng.normal(0, cfg.mocap_noise_m, pos.shape)


def _device_stamps(t: np.ndarray, clock: SynthClock, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    device = clock.offset_s + (1 + clock.drift_ppm * 1e-6) * t  # the sim's clock model
    recv = t + clock.latency_s + np.abs(rng.normal(0.0, clock.jitter_s, len(t)))
    return device, np.round(recv * NS).astype(np.int64)


def _echo_exchanges(clock: SynthClock, t_end: float, rng: np.random.Generator, every_s: float = 0.1) -> dict:
    """ECHO round trips every ``every_s``: symmetric 80 µs legs plus exponential queuing; QPC at 10 MHz."""
    send = np.arange(0.2, t_end, every_s)
    up = 80e-6 + rng.exponential(0.5e-3, len(send))
    down = 80e-6 + rng.exponential(0.5e-3, len(send))
    server_s = clock.offset_s + (1 + clock.drift_ppm * 1e-6) * (send + up)
    freq = 10_000_000
    return {
        "host_send_ns": np.round(send * NS).astype(np.int64).tolist(),
        "host_recv_ns": np.round((send + up + down) * NS).astype(np.int64).tolist(),
        "server_ticks": np.round(server_s * freq).astype(np.int64).tolist(),
        "clock_frequency": freq,
    }


def _general(cfg: SynthSession, cal: LoadCellCalibration) -> dict[str, Any]:
    """The synthetic session's ``/general``: a protocol of its steps, the calibration, a z-up geometry."""
    proto = {
        "name": f"synthetic_{cfg.rig}",
        "rig": cfg.rig,
        "backend": "sim",
        "sweep": {"frequencies": [s.frequency_hz for s in cfg.steps]},
        "settle_s": cfg.settle_s,
        "record_s": cfg.record_s,
        "amplitude_mm": cfg.amplitude_mm,
    }
    general = {
        "protocol": yaml.safe_dump(proto, sort_keys=False),
        "protocol_name": proto["name"],
        "rig": cfg.rig,
        "backend": "synthetic",
        "identity": {"generator": "beambench.analysis.synthetic"},
        "calibration": {"loadcells": cal.to_yaml()},
        "geometry": {"up_axis": "z", "forward_axis": "x"},
    }
    return general


def write_synthetic_session(path: str | Path, cfg: SynthSession) -> Path:
    """Write a session file with the truth of ``cfg``; returns its path."""
    from beambench.acquisition.batch import StepRecord
    from beambench.sinks.session_file.writer import SessionWriter

    rng = np.random.default_rng(cfg.seed)
    sched = _schedule(cfg)
    t_end = sched[-1][2] + 0.2
    k_stop = cfg.interrupted_in
    rows = sched  # the step rows written: every step, else those up to the one cut short
    if k_stop is not None:
        t_stop = sched[k_stop][1] + cfg.record_s / 2
        rows = [*sched[:k_stop], (sched[k_stop][0], sched[k_stop][1], t_stop)]
        t_end = t_stop + 0.2
    cal = cfg.calibration or default_calibration()
    names = (scene.body_marker, *WALKER_MARKERS[1:]) if (scene := scene_info(cfg.rig)).body_marker else CONTACT_MARKERS
    specs = [mocap_spec(names), motor_spec()] + ([loadcell_spec()] if scene.plate else [])
    clocks = {s.name: cfg.clocks.get(s.name, SynthClock()) for s in specs}

    batches: list[Batch] = []
    # mocap
    tm = np.arange(0.0, t_end, 1 / 360.0)
    keep = rng.random(len(tm)) >= cfg.mocap_dropout
    frame = np.arange(len(tm))[keep]
    tm = tm[keep]
    pos = markers(cfg, tm, rng)
    occ = rng.random(pos.shape[:2]) < cfg.occlusion
    pos[occ] = 0.0
    dev, host = _device_stamps(tm, clocks["mocap"], rng)
    batches.append(Batch("mocap", host, dev, {"data": pos, "frame": frame.astype(np.int64), "occluded": occ}))
    # motor
    tmo = np.arange(0.0, t_end, 0.01)
    turns = _crank_turns(cfg, sched, tmo)
    f_now = np.array([cfg.steps[i].frequency_hz if i >= 0 else 0.0 for i in _truth_at(cfg, sched, tmo)])
    dev, host = _device_stamps(tmo, clocks["motor"], rng)
    n = len(tmo)
    batches.append(
        Batch(
            "motor",
            host,
            dev,
            {
                "position": turns,
                "velocity": f_now + rng.normal(0, 0.01, n),
                "velocity_setpoint": f_now,
                "iq_measured": 0.5 + rng.normal(0, 0.05, n),
                "bus_voltage": np.full(n, 24.0),
                "axis_state": np.full(n, 8, np.int32),
                "axis_error": np.zeros(n, np.int64),
            },
        )
    )
    # load cells
    if scene.plate:
        tl = np.arange(0.0, t_end, 1e-3)
        tl_turns = _crank_turns(cfg, sched, tl - cfg.encoder_delay_s)
        fn, ft, _, _ = _contact_state(cfg, sched, tl, tl_turns)
        forces = np.stack([fn, ft], 1) + rng.normal(0, cfg.force_noise_n, (len(tl), 2))
        counts = np.round(cal.counts_from_force(forces)).astype(np.int32)
        dev, host = _device_stamps(tl, clocks["loadcell"], rng)
        batches.append(
            Batch(
                "loadcell",
                host,
                dev,
                {"data": counts, "seq": np.arange(len(tl)), "sync_edges": np.floor(tl * 360).astype(np.int64)},
            )
        )

    general = _general(cfg, cal)
    if cfg.natnet_echo:
        general["sync"] = {"natnet_echo": _echo_exchanges(clocks["mocap"], t_end, rng)}
    path = Path(path)
    writer = SessionWriter(path, general)
    writer.open(specs)
    try:
        # interleave batches in host-time order, like a live run
        for a in np.arange(0.0, t_end + cfg.batch_s, cfg.batch_s):
            lo, hi = int(a * NS), int((a + cfg.batch_s) * NS)
            for b in batches:
                sel = (b.host_time_ns >= lo) & (b.host_time_ns < hi)
                if sel.any():
                    writer.write(
                        Batch(
                            b.stream, b.host_time_ns[sel], b.device_time[sel], {k: v[sel] for k, v in b.columns.items()}
                        )
                    )
            for i, (s0, s1, s2) in enumerate(rows):
                if lo <= s2 * NS < hi:
                    st = cfg.steps[i]
                    times = (int(s0 * NS), int(s1 * NS), int(s2 * NS))
                    status = "aborted" if i == k_stop else "done"
                    writer.step(StepRecord(i, st.frequency_hz, *times, status, st.direction, st.kind, st.repeat))
        if k_stop is None:
            writer.event(int(t_end * NS), "stop", "synthetic session complete")
        else:
            writer.event(int(t_end * NS), "interrupted", "interrupted by user (SIGINT)")
    finally:
        writer.close()
    return path
