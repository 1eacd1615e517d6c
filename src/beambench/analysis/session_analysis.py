"""Analyse a recorded session: clocks onto one timeline, then per-step results on each record window.

``analyze_session(read_session(path))`` returns a :class:`SessionAnalysis` with a tidy per-step table
(``.table``, one row per step), the clock fits, the encoder↔marker delay and per-step arrays for figures.
``write_results`` stores it under ``/processing``. Everything here is read-only on the raw data.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from beambench.acquisition.forces.contact_events import ContactParams, Contacts, force_contacts
from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration, default_calibration
from beambench.acquisition.protocol.scenes import scene_or_unknown
from beambench.analysis.branches import annotate_branches, with_step_labels
from beambench.analysis.contact import touchdown_velocity
from beambench.analysis.drift import drift_corrected
from beambench.analysis.path_shape import annotate_inversions, path_noise, shape_columns
from beambench.analysis.signals import velocity
from beambench.analysis.speed_tracking import TrackResult, track_result
from beambench.analysis.step_contacts import analysis_frequency, motor_frequency, stage_sine
from beambench.analysis.sync import (
    NS,
    ClockFit,
    DelayEstimate,
    EdgeCheck,
    encoder_marker_delay,
    fit_clock,
    fit_echo,
    fits_table,
    hold_previous,
    resample,
    sync_edge_check,
    timeline,
)
from beambench.analysis.trajectory import (
    Ellipse,
    StageFrame,
    area_per_cycle,
    axis_vector,
    fit_ellipse_harmonic,
    relative_trajectory,
    stage_frame,
)
from beambench.analysis.walking import body_speed
from beambench.sinks.session_file.frames import flat_names, step_of
from beambench.sinks.session_file.reader import StreamData, run_ending


@dataclass(frozen=True)
class AnalysisOptions:
    """Choices of the analysis. Axes are world (mocap) axes such as ``"z"`` or ``"-y"``; None = from the session."""

    up: str | None = None
    forward: str | None = None
    contact: ContactParams = field(default_factory=ContactParams)
    stage_marker: str = "stage"
    tip_marker: str = "tip"
    foot_marker: str = "foot"
    body_marker: str = ""  # "": the session's scene's (SceneInfo.body_marker; none where the rig does not walk)
    walker_feet: tuple[str, ...] = ("foot_left", "foot_right")
    drift_correct: bool = False  # add <metric>_drift_corrected columns (beambench.analysis.drift.drift_corrected)


@dataclass
class StepResult:
    """One step's record window: the table row plus arrays for figures (times in s from the window start)."""

    index: int
    frequency_hz: float
    row: dict[str, Any]
    t_mocap: np.ndarray = field(default_factory=lambda: np.zeros(0))
    markers: dict[str, np.ndarray] = field(default_factory=dict)  # label → (n, 3) m, world, at t_mocap
    paths: dict[str, np.ndarray] = field(default_factory=dict)  # marker → (n, 2) mm in the stage frame
    ellipses: dict[str, Ellipse] = field(default_factory=dict)
    t_force: np.ndarray = field(default_factory=lambda: np.zeros(0))
    force: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (normal, tangential) N
    contacts: Contacts | None = None
    touchdown_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # foot at touchdown, stage frame
    touchdown_v: np.ndarray = field(default_factory=lambda: np.zeros(0))  # mm/s along drive, vs plate
    body_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    body_x_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class SessionAnalysis:
    """Everything :func:`analyze_session` found; ``table`` is the tidy per-step DataFrame."""

    path: Path | None
    rig: str
    backend: str
    protocol_name: str
    general: dict[str, Any]
    fits: dict[str, ClockFit]
    delay: DelayEstimate | None
    frame: StageFrame | None
    table: pd.DataFrame
    steps: list[StepResult]
    calibration_source: str = ""
    residuals_us: dict[str, np.ndarray] = field(default_factory=dict)
    residual_t_s: dict[str, np.ndarray] = field(default_factory=dict)
    edge_check: EdgeCheck | None = None
    name: str = ""
    track: TrackResult | None = None  # speed tracking (track: sessions), beambench.analysis.speed_tracking
    ending: tuple[str, str] | None = None  # the run's closing event (kind, message); None: the file has none

    @property
    def sync_table(self) -> pd.DataFrame:
        return fits_table(self.fits)

    @property
    def label(self) -> str:
        """How figures and tables name this session: ``name`` if set, else the file stem."""
        if self.name:
            return self.name
        return self.path.stem if self.path is not None else self.protocol_name


# ------------------------------------------------------------------------------------------------ helpers


def _text(value: Any) -> str:
    return value if isinstance(value, str) else ""


def session_calibration(general: dict[str, Any]) -> LoadCellCalibration:
    """The load-cell calibration stored in the session (``/general/calibration/loadcells``), else the default."""
    cal = general.get("calibration")
    text = cal.get("loadcells") if isinstance(cal, dict) else general.get("calibration/loadcells")
    if isinstance(text, str) and text.strip():
        try:
            data = yaml.safe_load(text)
            if isinstance(data, dict):
                return LoadCellCalibration.from_dict(data)
        except (yaml.YAMLError, KeyError, ValueError):
            pass
    return default_calibration()


def _protocol_dict(general: dict[str, Any]) -> dict[str, Any]:
    try:
        data = yaml.safe_load(_text(general.get("protocol", "")))
    except yaml.YAMLError:
        return {}
    return data if isinstance(data, dict) else {}


def session_rig(general: dict[str, Any]) -> str:
    """The rig a session was recorded on (its /general, else its protocol's; contact by default)."""
    return _text(general.get("rig")) or str(_protocol_dict(general).get("rig", "contact"))


def _geometry_axis(general: dict[str, Any], key: str) -> str | None:
    """An axis named in the session (``/general/<key>`` or ``/general/geometry/<key>``), if any."""
    for src in (general, general.get("geometry") if isinstance(general.get("geometry"), dict) else {}):
        v = src.get(key) if isinstance(src, dict) else None
        if isinstance(v, str) and v.strip():
            return v.strip()
    return None


def stream_host_times(stream: Any, fit: ClockFit | None) -> np.ndarray:
    """Event times of a stream on the host clock (ns): the clock fit applied to the device stamps; a sample whose
    device stamp the fit cannot place (damaged: NaN, 1e300) keeps its own receive time."""
    if fit is None or fit.method in ("none",):
        return np.asarray(stream.host_time_ns, np.int64)
    return fit.host_times(stream.device_time, stream.host_time_ns)


def fit_session_clocks(session: Any) -> dict[str, ClockFit]:
    """One device→host clock fit per stream with samples (lower envelope of the receive stamps).

    When the session holds NatNet ECHO exchanges (``/general/sync/natnet_echo``: ``host_send_ns``,
    ``host_recv_ns``, ``server_ticks``, ``clock_frequency``), their minimum-round-trip fit is added as
    ``mocap_echo``: a cross-check whose offset from the ``mocap`` fit is Motive's one-way latency (mid-exposure
    to host receipt), which one-way stamps cannot see. Streams are still mapped by their own fits.
    """
    fits = {
        name: fit_clock(s.device_time, s.host_time_ns, name)
        for name, s in session.streams.items()
        if len(s.host_time_ns) > 0
    }
    echo = natnet_echo_fit(session.general)
    if echo is not None:
        fits["mocap_echo"] = echo
    return fits


def natnet_echo_fit(general: dict[str, Any]) -> ClockFit | None:
    """The ECHO-exchange clock fit from ``/general/sync/natnet_echo``, if the session has one."""
    sync = general.get("sync")
    table = sync.get("natnet_echo") if isinstance(sync, dict) else None
    if not isinstance(table, dict):
        return None
    try:
        freq = float(table["clock_frequency"])
        send = np.asarray(table["host_send_ns"], np.int64)
        recv = np.asarray(table["host_recv_ns"], np.int64)
        ticks = np.asarray(table["server_ticks"], np.float64)
        if freq <= 0 or len(send) == 0:
            return None
        return fit_echo(send, recv, ticks / freq, "mocap_echo")
    except (KeyError, TypeError, ValueError):
        return None


def mocap_markers(stream: StreamData) -> tuple[list[str], np.ndarray]:
    """Marker labels and positions ``(n, M, 3)`` in metres, NaN where occluded."""
    data = np.array(stream.columns["data"], dtype=np.float64)
    spec = stream.spec
    labels = list(spec.columns["data"].labels) if "data" in spec.columns else []
    if len(labels) != data.shape[1]:
        labels = [f"m{i}" for i in range(data.shape[1])]
    occ = stream.columns.get("occluded")
    if occ is not None and len(occ) == len(data):
        data[np.asarray(occ, bool)] = np.nan
    return labels, data


def _window(t_ns: np.ndarray, a: int, b: int) -> slice:
    return slice(int(np.searchsorted(t_ns, a, "left")), int(np.searchsorted(t_ns, b, "left")))


def _sorted(t_ns: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    if len(t_ns) > 1 and np.any(np.diff(t_ns) < 0):
        order = np.argsort(t_ns, kind="stable")
        return (t_ns[order], *(a[order] for a in arrays))
    return (t_ns, *arrays)


def _sense(e: Ellipse) -> str:
    return "" if e.clockwise is None else ("cw" if e.clockwise else "ccw")


def _sign(x: float) -> int:
    return 0 if not np.isfinite(x) or x == 0 else int(np.sign(x))


# ---------------------------------------------------------------------------------------------- analysis


@dataclass(frozen=True)
class StepArrays:
    """One step's record window of every stream on the host clock: times in s from the window start, marker
    positions in m (world, NaN where occluded), motor speed in turn/s, plate force (normal, tangential) in N,
    motor quadrature current in A (NaN where the motor does not report it)."""

    t_mocap: np.ndarray
    markers: dict[str, np.ndarray]
    motor_velocity: np.ndarray
    t_force: np.ndarray
    force: np.ndarray
    motor_current: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def marker(self, label: str) -> np.ndarray | None:
        return self.markers.get(label)


@dataclass(frozen=True)
class HostStreams:
    """The session's mocap, motor and load-cell streams on the host clock (ns, sorted), cut into steps by
    :meth:`window`."""

    mocap_t: np.ndarray
    markers: dict[str, np.ndarray]  # label → (n, 3) m
    motor_t: np.ndarray
    motor_position: np.ndarray
    motor_velocity: np.ndarray
    force_t: np.ndarray
    force: np.ndarray  # (n, 2) N
    motor_current: np.ndarray = field(default_factory=lambda: np.zeros(0))  # A, at motor_t

    @property
    def last_ns(self) -> int:
        return max([int(a[-1]) for a in (self.mocap_t, self.force_t, self.motor_t) if len(a)], default=0)

    def window(self, a: int, b: int) -> StepArrays:
        wm, wl, wv = _window(self.mocap_t, a, b), _window(self.force_t, a, b), _window(self.motor_t, a, b)
        return StepArrays(
            (self.mocap_t[wm] - a) / NS,
            {k: v[wm] for k, v in self.markers.items()},
            self.motor_velocity[wv],
            (self.force_t[wl] - a) / NS,
            self.force[wl],
            self.motor_current[wv] if len(self.motor_current) == len(self.motor_t) else np.zeros(0),
        )


@dataclass(frozen=True)
class StepContext:
    """What every step's analysis needs besides its arrays: the session's facts and the stage frame."""

    rig: str
    amplitude_mm: float
    has_force: bool  # the session has load-cell data (contacts are then analysed in every step)
    options: AnalysisOptions
    frame: StageFrame | None
    forward: str


def host_streams(session: Any, fits: dict[str, ClockFit], cal: LoadCellCalibration) -> HostStreams:
    """Mocap markers, motor position/speed and calibrated plate force of a session on the host clock."""
    mocap = session.streams.get("mocap")
    mt, markers = np.zeros(0, np.int64), {}
    if mocap is not None and len(mocap.host_time_ns):
        labels, pos = mocap_markers(mocap)
        mt, pos = _sorted(stream_host_times(mocap, fits.get("mocap")), pos)
        markers = {lbl: pos[:, i] for i, lbl in enumerate(labels)}
    motor = session.streams.get("motor")
    mot_t, mot_pos, mot_vel, mot_iq = np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0)
    if motor is not None and len(motor.host_time_ns):
        nan = np.full(len(motor.host_time_ns), np.nan)
        mot_t, mot_pos, mot_vel, mot_iq = _sorted(
            stream_host_times(motor, fits.get("motor")),
            np.asarray(motor.columns.get("position", nan), float),
            np.asarray(motor.columns.get("velocity", nan), float),
            np.asarray(motor.columns.get("iq_measured", nan), float),
        )
    lc = session.streams.get("loadcell")
    lc_t, force = np.zeros(0, np.int64), np.zeros((0, 2))
    if lc is not None and len(lc.host_time_ns):
        lc_t, force = _sorted(stream_host_times(lc, fits.get("loadcell")), cal.force_from_counts(lc.columns["data"]))
    return HostStreams(mt, markers, mot_t, mot_pos, mot_vel, lc_t, force, mot_iq)


def _session_frame(
    general: dict[str, Any], options: AnalysisOptions, markers: dict[str, np.ndarray]
) -> tuple[StageFrame | None, str]:
    """The stage frame (drive, up) — from the stage marker, else the walker's forward axis — and the forward axis."""
    stage, body = markers.get(options.stage_marker), markers.get(options.body_marker)
    up = options.up or _geometry_axis(general, "up_axis")
    forward = options.forward or _geometry_axis(general, "forward_axis") or "x"
    ref = stage if stage is not None else body
    if ref is None or np.isfinite(ref).all(axis=1).sum() < 3:
        return None, forward
    try:
        if stage is not None:
            hanging = markers.get(options.foot_marker)
            return stage_frame(stage[:: max(1, len(stage) // 20000)], up, hanging_xyz=hanging), forward
        d = axis_vector(forward)
        u = axis_vector(up) if up else _guess_up(d)
        u = u - (u @ d) * d
        return StageFrame(d, u / np.linalg.norm(u)), forward
    except ValueError:
        return None, forward


def _clock_residuals(session: Any, fits: dict[str, ClockFit]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Each stream's receive delay above its clock fit (µs) and the sample times (s from the session's start)."""
    residuals = {
        n: fits[n].residuals_us(s.device_time, s.host_time_ns).astype(np.float32)
        for n, s in session.streams.items()
        if n in fits
    }
    t_first = min((int(s.host_time_ns.min()) for s in session.streams.values() if len(s.host_time_ns)), default=0)
    residual_t = {n: ((session.streams[n].host_time_ns - t_first) / NS).astype(np.float32) for n in residuals}
    return residuals, residual_t


def _edge_check(session: Any, fits: dict[str, ClockFit]) -> EdgeCheck | None:
    lc, mocap = session.streams.get("loadcell"), session.streams.get("mocap")
    if lc is None or mocap is None or "sync_edges" not in lc.columns or "frame" not in mocap.columns:
        return None
    if not len(lc.host_time_ns):
        return None
    return sync_edge_check(
        stream_host_times(lc, fits.get("loadcell")),
        lc.columns["sync_edges"],
        stream_host_times(mocap, fits.get("mocap")),
        mocap.columns["frame"],
    )


def analyze_session(
    session: Any,
    options: AnalysisOptions = AnalysisOptions(),
    progress: Callable[[int, int], None] | None = None,
) -> SessionAnalysis:
    """Analyse every step of a session (as returned by :func:`beambench.sinks.session_file.reader.read_session`)."""
    general = dict(session.general)
    proto = _protocol_dict(general)
    rig = session_rig(general)
    options = replace(options, body_marker=options.body_marker or scene_or_unknown(rig).body_marker or "")
    backend = _text(general.get("backend")) or str(proto.get("backend", ""))
    name = _text(general.get("protocol_name")) or str(proto.get("name", ""))
    amplitude_mm = float(proto.get("amplitude_mm", np.nan)) if proto else float("nan")
    cal = session_calibration(general)
    fits = fit_session_clocks(session)
    residuals, residual_t = _clock_residuals(session, fits)
    streams = host_streams(session, fits, cal)
    frame, forward = _session_frame(general, options, streams.markers)
    delay = None
    stage = streams.markers.get(options.stage_marker)
    if stage is not None and frame is not None and len(streams.motor_t) > 4:
        disp = (stage - np.nanmean(stage, axis=0)) @ frame.drive
        delay = encoder_marker_delay(streams.motor_t, streams.motor_position, streams.mocap_t, disp)

    ctx = StepContext(rig, amplitude_mm, len(streams.force_t) > 0, options, frame, forward)
    results: list[StepResult] = []
    n_steps, last_ns = len(session.steps), streams.last_ns
    steps: Any = with_step_labels(session.steps)  # a session's own columns: read by name
    for k, srow in enumerate(steps.itertuples(index=False)):
        a = int(srow.t_settled_ns)
        b = int(srow.t_end_ns) if int(srow.t_end_ns) > 0 else last_ns
        results.append(_analyze_step(srow, a, b, streams.window(a, b) if 0 <= a < b else None, ctx))
        if progress is not None:
            progress(k + 1, n_steps)
    _shapes(results)
    table = pd.DataFrame([r.row for r in results])
    body = streams.markers.get(options.body_marker)
    track = track_result(session.streams.get("track"), session.steps, streams.mocap_t, body, forward)
    if track is not None and track.segments:  # per-segment target, error, settling and direction times
        table = table.merge(pd.DataFrame(track.segments), on="step", how="left")
    return SessionAnalysis(
        Path(session.path),
        rig,
        backend,
        name,
        general,
        fits,
        delay,
        frame,
        _annotated(table, options),
        results,
        cal.source,
        residuals,
        residual_t,
        _edge_check(session, fits),
        track=track,
        ending=run_ending(session.events),
    )


def _shapes(results: list[StepResult]) -> None:
    """Each step's path shape (crossings, loop sense) above the session's mocap noise floor."""
    tracked = [r for r in results if r.paths and np.isfinite(r.row.get("analysis_frequency_hz", np.nan))]
    noise = path_noise([(r.paths, r.t_mocap, float(r.row["analysis_frequency_hz"])) for r in tracked])
    for r in tracked:
        f = float(r.row["analysis_frequency_hz"])
        r.row.update(shape_columns(r.paths, r.t_mocap, f, str(r.row.get("regime", "")), noise))
    if tracked:
        for r in results:
            r.row["path_noise_mm"] = noise


def _annotated(table: pd.DataFrame, options: AnalysisOptions) -> pd.DataFrame:
    """The per-step table with branches, repeats, path inversions and (on request) drift-corrected columns."""
    t = annotate_inversions(annotate_branches(table))
    return drift_corrected(t) if options.drift_correct else t


def _guess_up(drive: np.ndarray) -> np.ndarray:
    for ax in ("z", "y", "x"):
        v = axis_vector(ax)
        if abs(v @ drive) < 0.9:
            return v
    return axis_vector("z")


def _analyze_step(srow: Any, a: int, b: int, arr: StepArrays | None, ctx: StepContext) -> StepResult:
    """One step's table row and figure arrays from its record window ``a``…``b`` (ns; ``arr`` None if empty)."""
    f_cmd = float(srow.frequency_hz)
    row: dict[str, Any] = {
        "step": int(srow.index),
        "frequency_hz": f_cmd,
        "status": str(srow.status),
        "direction": str(srow.direction),
        "kind": str(srow.kind),
        "repeat": int(srow.repeat),
        "t_settled_s": a / NS if a >= 0 else np.nan,
        "record_s": (b - a) / NS if a >= 0 else np.nan,
    }
    res = StepResult(int(srow.index), f_cmd, row)
    if arr is None:
        row["regime"] = ""
        return res
    res.t_mocap, res.markers = arr.t_mocap, arr.markers
    f_use = _drive(row, arr, ctx, f_cmd)
    _paths(res, arr, ctx, f_use)
    if ctx.has_force:
        _contacts(res, arr, ctx, f_use)
    else:
        row["regime"] = ""
    body = arr.marker(ctx.options.body_marker)
    if body is not None:  # walker: body speed
        sp = body_speed(arr.t_mocap, body, ctx.forward)
        row["body_speed_mm_s"] = sp.speed_mm_s
        row["body_speed_stderr_mm_s"] = sp.stderr_mm_s
        res.body_t = arr.t_mocap
        res.body_x_mm = body @ axis_vector(ctx.forward) * 1e3
    row["analysis_frequency_hz"] = f_use
    return res


def _drive(row: dict[str, Any], arr: StepArrays, ctx: StepContext, f_cmd: float) -> float:
    """Motor speed (crank turn/s = Hz), the stage's measured frequency and amplitude; returns the frequency the
    rest of the step is analysed at (measured, else the motor's, else the commanded)."""
    row["motor_frequency_hz"] = motor_frequency(arr.motor_velocity)
    iq = arr.motor_current
    row["motor_current_rms_a"] = float(np.sqrt(np.nanmean(iq**2))) if np.isfinite(iq).any() else np.nan
    stage = arr.marker(ctx.options.stage_marker)
    if stage is not None and ctx.frame is not None:
        row["mocap_valid_fraction"] = float(np.isfinite(stage).all(axis=1).mean()) if len(stage) else 0.0
    sine = stage_sine(arr.t_mocap, stage, ctx.frame, f_cmd)
    row["measured_frequency_hz"] = sine.frequency_hz
    row["frequency_error_hz"] = sine.frequency_hz - f_cmd
    row["stage_amplitude_mm"] = sine.amplitude * 1e3
    row["commanded_amplitude_mm"] = ctx.amplitude_mm if stage is not None else np.nan
    return analysis_frequency(sine, row["motor_frequency_hz"], f_cmd)


def _paths(res: StepResult, arr: StepArrays, ctx: StepContext, f_use: float) -> None:
    """Tip and foot paths in the stage frame (the walker's feet relative to the body) and their ellipses."""
    opt, t, row = ctx.options, arr.t_mocap, res.row
    stage = arr.marker(opt.stage_marker)
    ref = stage if stage is not None else arr.marker(opt.body_marker)
    if ctx.frame is None or ref is None:
        return
    tracked = {"tip": opt.tip_marker, "foot": opt.foot_marker} if stage is not None else {f: f for f in opt.walker_feet}
    for name, label in tracked.items():
        m = arr.marker(label)
        if m is None:
            continue
        xy = relative_trajectory(m, ref, ctx.frame)
        res.paths[name] = xy
        e = fit_ellipse_harmonic(t, xy, f_use)
        res.ellipses[name] = e
        row[f"{name}_major_mm"] = e.major
        row[f"{name}_minor_mm"] = e.minor
        row[f"{name}_tilt_deg"] = e.tilt_deg
        row[f"{name}_sense"] = _sense(e)
        row[f"{name}_ellipse_r2"] = e.r2
        row[f"{name}_area_mm2"] = area_per_cycle(t, xy, f_use)


def _contacts(res: StepResult, arr: StepArrays, ctx: StepContext, f_use: float) -> None:
    """Contacts from the calibrated normal force, the tangential force in contact, the foot's direction at
    touchdown."""
    tf, fw, row = arr.t_force, arr.force, res.row
    res.t_force, res.force = tf, fw
    # the regime from the normal force alone, as the paper's: the mocap's 0.1 mm noise exceeds the foot's
    # rise in a chattering contact, so a foot-height test would make the label depend on the noise
    c, s = force_contacts(tf, fw[:, 0], f_use, ctx.options.contact)
    res.contacts = c
    row.update(
        n_contacts=s.n_contacts,
        contact_frequency_hz=s.contact_frequency_hz,
        contacts_per_cycle=s.contacts_per_cycle,
        regime=s.regime,
        in_contact_fraction=s.in_contact_fraction,
        peak_normal_n=float(np.nanmax(fw[:, 0])) if len(fw) else np.nan,
        contact_threshold_n=c.on_n,
    )
    ft_in = fw[c.mask, 1] if len(fw) else np.zeros(0)
    mean_ft = float(np.nanmean(ft_in)) if np.isfinite(ft_in).any() else np.nan
    row["mean_tangential_n"] = mean_ft
    row["tangential_sign"] = _sign(mean_ft)
    # direction of motion at touchdown: foot velocity along the drive axis, relative to the plate
    td, t = c.touchdown_s, arr.t_mocap
    foot = arr.marker(ctx.options.foot_marker)
    if foot is None or ctx.frame is None or not len(td):
        row["touchdown_velocity_mm_s"] = np.nan
        row["touchdown_direction"] = 0
        return
    fv = velocity(t, foot @ ctx.frame.drive * 1e3)
    tv = touchdown_velocity(td, t, fv, 0.1 / f_use)
    res.touchdown_v = tv
    rel = res.paths.get("foot")
    if rel is not None and len(t) > 1:
        res.touchdown_xy = np.column_stack([np.interp(td, t, rel[:, 0]), np.interp(td, t, rel[:, 1])])
    med = float(np.nanmedian(tv)) if np.isfinite(tv).any() else np.nan
    row["touchdown_velocity_mm_s"] = med
    row["touchdown_direction"] = _sign(med)


# ------------------------------------------------------------------------------------- storing / notebooks


def contacts_table(analysis: SessionAnalysis) -> pd.DataFrame:
    """One row per contact interval of every step (times in s from the step's window start)."""
    rows = []
    for r in analysis.steps:
        c = r.contacts
        if c is None:
            continue
        tdv = iter(r.touchdown_v) if len(r.touchdown_v) == c.n_touchdowns else None
        for s, e, td in zip(c.start_s, c.end_s, c.touchdown):
            v = next(tdv) if (td and tdv is not None) else np.nan
            rows.append(
                {
                    "step": r.index,
                    "frequency_hz": r.frequency_hz,
                    "start_s": s,
                    "end_s": e,
                    "touchdown": bool(td),
                    "touchdown_velocity_mm_s": v,
                }
            )
    cols = ["step", "frequency_hz", "start_s", "end_s", "touchdown", "touchdown_velocity_mm_s"]
    return pd.DataFrame(rows, columns=cols)


def write_results(analysis: SessionAnalysis, path: str | Path | None = None) -> None:
    """Store the per-step table, clock fits (+ residuals), contacts and the delay under ``/processing``."""
    from beambench.sinks.session_file.writer import write_processing

    target = Path(path) if path is not None else analysis.path
    if target is None:
        raise ValueError("no session path to write to")
    write_processing(target, "steps", analysis.table)
    write_processing(target, "sync", analysis.sync_table)
    write_processing(target, "sync_residuals_us", analysis.residuals_us)  # row-aligned with /acquisition
    write_processing(target, "contacts", contacts_table(analysis))
    e = analysis.edge_check
    if e is not None:
        write_processing(target, "sync_edge_check", {k: np.array([v]) for k, v in asdict(e).items()})
    d = analysis.delay
    if d is not None:
        write_processing(
            target,
            "encoder_marker_delay",
            {
                "delay_s": np.array([d.delay_s]),
                "quality": np.array([d.quality]),
                "n": np.array([d.n]),
                "frequency_span_hz": np.array([d.frequency_span_hz]),
            },
        )


def resample_session(
    session: Any,
    rate_hz: float = 1000.0,
    fits: dict[str, ClockFit] | None = None,
    start_ns: int | None = None,
    end_ns: int | None = None,
) -> pd.DataFrame:
    """Every stream's numeric columns on one uniform host-clock timeline (a DataFrame indexed by ``t_s``, seconds
    from the earliest sample), for notebooks.

    Columns are named ``<stream>/<column>`` with the column names of ``SessionFile.to_pandas`` (``mocap/foot_x``,
    ``mocap/foot_occluded``, ``loadcell/lc0``, ``motor/axis_state``); load cells
    also get calibrated ``loadcell/normal_n`` and ``loadcell/tangential_n``, and ``step`` is the protocol step
    each row falls in (-1 between steps). Float columns are interpolated linearly (NaN where a stream has no data
    or a gap); integer, boolean and enum columns (frame and sequence numbers, occlusion flags, the ODrive's
    ``axis_state``) keep the last sample at or before each row (nullable ``Int64`` / ``boolean``, NA where there is
    none), so a state never takes a value it was not in. The raw data are not modified.
    """
    fits = fits if fits is not None else fit_session_clocks(session)
    times = {n: stream_host_times(s, fits.get(n)) for n, s in session.streams.items() if len(s.host_time_ns)}
    if not times:
        return pd.DataFrame()
    a = start_ns if start_ns is not None else min(int(t.min()) for t in times.values())
    b = end_ns if end_ns is not None else max(int(t.max()) for t in times.values())
    grid = timeline(a, b, rate_hz)
    out: dict[str, Any] = {}
    cal = session_calibration(session.general)
    for name, t in times.items():
        s = session.streams[name]
        cols = dict(s.columns)
        if name == "mocap" and "data" in cols:
            labels, pos = mocap_markers(s)
            cols["data"] = pos
        if name == "loadcell" and "data" in cols:
            fcal = cal.force_from_counts(cols["data"])
            out["loadcell/normal_n"] = resample(t, fcal[:, 0], grid)
            out["loadcell/tangential_n"] = resample(t, fcal[:, 1], grid)
        for col, values in cols.items():
            arr = np.asarray(values)
            if arr.dtype.kind not in "fiub":
                continue
            labels = list(s.spec.columns[col].labels) if col in s.spec.columns else []
            names = _column_names(name, col, arr.shape[1:], labels)
            if arr.dtype.kind == "f":
                flat = resample(t, arr, grid).reshape(len(grid), -1)
                for i, nm in enumerate(names):
                    out[nm] = flat[:, i]
                continue
            held, valid = hold_previous(t, arr, grid)
            flat = held.reshape(len(grid), -1)
            for i, nm in enumerate(names):
                held_i = pd.Series(flat[:, i])
                typed = held_i.astype("boolean") if arr.dtype.kind == "b" else held_i.astype("Int64")
                out[nm] = typed.mask(~valid).array
    out["step"] = step_of(session, grid)[0]
    return pd.DataFrame(out, index=pd.Index((grid - a) / NS, name="t_s"))


def _column_names(stream: str, col: str, shape: tuple[int, ...], labels: list[str]) -> list[str]:
    """``<stream>/<name>`` with the names of ``SessionFile.to_pandas`` (``mocap/foot_x``, ``loadcell/lc0``)."""
    return [f"{stream}/{name}" for name in flat_names(stream, col, shape, tuple(labels))]
