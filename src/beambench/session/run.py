"""Wire one run together: rig + sinks (HDF5 session, Rerun) + runner with a progress bar."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from rich.progress import (
    BarColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from beambench.acquisition.capabilities import (
    DeviceFault,
    HasSilenceTimeouts,
    ReportsAfterRun,
    ReportsComputedAhead,
    Rig,
    WarnsOfModel,
)
from beambench.acquisition.forces.loadcell_calibration import default_calibration
from beambench.acquisition.hub import Hub, Sink
from beambench.acquisition.monitors import build_monitors
from beambench.acquisition.protocol.backends import backend_info
from beambench.acquisition.protocol.plan import plan, step_name
from beambench.acquisition.protocol.schema import Backend, ConfigError, Protocol
from beambench.acquisition.runner import Runner, RunResult
from beambench.acquisition.stop_signals import StopSignal, stop_on_signals
from beambench.backends.build import build_rig
from beambench.common.console import LogProgress, stderr_console
from beambench.common.errors import BeambenchError
from beambench.session.checks import Validated, validate
from beambench.session.provenance import provenance
from beambench.session.track_map import track_setup
from beambench.sinks import RerunMode  # rerun itself is imported only when a viewer is wanted
from beambench.sinks.hdf5 import SessionFileError, SessionWriter, append_general


@dataclass(frozen=True)
class RunRequest:
    """What one run needs: the protocol (parsed and as written), where it runs and where its files go."""

    protocol: Protocol
    protocol_text: str
    backend: Backend
    path: Path
    rerun_mode: RerunMode = "off"
    realtime: bool = False
    rig_file: Path | None = None
    can_log: Path | None = None
    show_progress: bool = True
    label: str = ""  # before each progress description: the phase of a run in two (``speed map: ``)
    validated: Validated | None = None
    """The protocol already checked for ``backend`` (:func:`beambench.session.checks.validate`); None: checked here."""


class RigStartError(BeambenchError):
    """The rig could not start (a device or an emulated peer lost while opening): one line, motor idled."""


def run_session(
    protocol: Protocol,
    protocol_text: str,
    backend: Backend,
    path: Path,
    rerun_mode: RerunMode = "off",
    realtime: bool = False,
    rig_file: Path | None = None,
    can_log: Path | None = None,
    show_progress: bool = True,
) -> RunResult:
    """Run ``protocol`` on ``backend`` and save the session at ``path`` (and ``.rrd`` beside it with save): the
    :class:`RunRequest` of these arguments, through :func:`run_request`."""
    return run_request(
        RunRequest(protocol, protocol_text, backend, path, rerun_mode, realtime, rig_file, can_log, show_progress)
    )


def _count(n: int, what: str) -> str:
    return f"{n} {what}{'' if n == 1 else 's'}"


def _say(show: bool, text: str) -> None:
    """A note on stderr (with the progress; a terminal gone only loses it)."""
    if show:
        with contextlib.suppress(OSError):
            stderr_console().print(text, soft_wrap=True, markup=False, highlight=False)


def _run_twin(sweep: Protocol, text: str, path: Path, show_progress: bool) -> tuple[str, str]:
    """A ``track: map: twin`` run's first phase, its sweep on the sim (:func:`beambench.session.track_map.twin_map`),
    said as such with where its session goes."""
    steps = plan(sweep)
    _say(
        show_progress,
        f"phase 1 of 2, the speed map (track.map: twin): this protocol's sweep on the sim, {_count(len(steps), 'step')}, "
        f"{sum(s.duration_s for s in steps):g} s of rig time, into {path}",
    )
    result = run_request(RunRequest(sweep, text, "sim", path, show_progress=show_progress, label="speed map: "))
    if result.status == "completed":
        size = path.stat().st_size / 1e6 if path.is_file() else 0.0
        _say(show_progress, f"speed map: {path} ({size:.1f} MB, kept: track.map: {path} reuses it without the sweep)")
    return result.status, result.message


def run_request(request: RunRequest, then_ignore_signals: bool = False) -> RunResult:
    """Run one :class:`RunRequest`.

    From the first line on, every stop signal (:data:`beambench.acquisition.stop_signals.STOP_SIGNALS`: SIGINT, SIGTERM,
    SIGHUP, SIGQUIT, …) only requests a stop: a signal while the rig opens still yields a session that ends
    ``interrupted`` with the motor idled. A rig that cannot start raises :class:`RigStartError`; a session file
    that cannot be created or written at the start, :class:`~beambench.acquisition.hub.SinkFailure`.
    ``then_ignore_signals``: the stop signals stay ignored after the run (for a command about to exit).
    """
    with stop_on_signals(then_ignore=then_ignore_signals) as stop:
        return _run_session(request, stop)


def _open_rig(req: RunRequest, checked: Validated) -> Rig:
    """Build and open the rig; a device or peer lost meanwhile is one :class:`RigStartError` (rig closed)."""
    try:
        rig = build_rig(checked.slices, req.backend, realtime=req.realtime, rig_file=req.rig_file, can_log=req.can_log)
        rig.open()
    except (DeviceFault, OSError, EOFError) as exc:
        if isinstance(exc, ConfigError):
            raise
        why = str(exc) or type(exc).__name__
        raise RigStartError(f"the {req.backend} rig did not start: {why}") from None
    return rig


def _announce_profile(req: RunRequest) -> None:
    """A ``track: map: twin`` run's second phase, its profile, said as such (the map was phase 1)."""
    track = req.protocol.track
    if track is None or track.map != "twin":
        return
    rig_s = sum(s.duration_s for s in plan(req.protocol))
    _say(
        req.show_progress,
        f"phase 2 of 2, the profile: {_count(len(track.segments), 'segment')}, {rig_s:g} s of rig time on the "
        f"{req.backend} backend, into {req.path}",
    )


def _run_session(req: RunRequest, stop: StopSignal) -> RunResult:
    protocol, path, backend = req.protocol, req.path, req.backend
    checked = req.validated or validate(protocol, backend, can_log=req.can_log)
    tracking = track_setup(protocol, path, _run_twin, req.show_progress) if protocol.track is not None else None
    _announce_profile(req)
    reserved = path.with_suffix(".rrd") if req.rerun_mode == "save" else None
    if reserved is not None:
        _reserve(reserved)
    try:
        rig = _open_rig(req, checked)
    except BaseException:
        _unreserve(reserved)
        raise
    steps = checked.steps
    try:
        general = {
            "protocol": req.protocol_text,
            "protocol_name": protocol.name,
            "rig": protocol.rig,
            "backend": backend,
            "identity": rig.identity(),
            "calibration": {"loadcells": default_calibration().to_yaml()},
            **provenance(),
        }
        model_warnings = rig.model_warnings() if isinstance(rig, WarnsOfModel) else []
        if model_warnings:  # known before the first step: a killed run keeps them too
            general["warnings"] = model_warnings
        specs = [s.describe() for s in rig.streams]
        if tracking is not None:  # the controller's decisions are a stream; it reads the mocap as a sink
            specs.append(tracking.spec)
            general["track_map"] = tracking.map_info
        frames = [s.frame for s in specs if s.frame is not None]
        if frames:  # the mocap's world axes, which analysis needs (Motive: y up)
            general["geometry"] = frames[0].as_dict()
        writer = SessionWriter(path, general)
        sinks: list[Sink] = [writer]
        silence = rig.silence_timeouts() if isinstance(rig, HasSilenceTimeouts) else None
        monitors = build_monitors(protocol, [s.name for s in specs], silence)
        sinks += monitors
        if tracking is not None:
            sinks.append(tracking.controller)
        if req.rerun_mode != "off":
            from beambench.analysis.step_contacts import window_contacts
            from beambench.sinks.rerun_view import RerunSink

            sinks.append(
                RerunSink(
                    req.rerun_mode,
                    path.stem,
                    path.with_suffix(".rrd"),
                    t0_ns=rig.clock.now_ns(),
                    calibration=default_calibration(),  # the one stored in /general: forces in N live
                    rig=protocol.rig,
                    total_steps=len(steps),
                    step_contacts=window_contacts,  # the step panel's regimes are the report's
                )
            )
        hub = Hub(sinks, critical=(writer,))
        hub.open(specs)
    except BaseException:
        rig.close()
        _unreserve(reserved)  # the run never started: no empty recording left behind
        raise
    with _progress(req.show_progress) as progress:
        task = progress.add_task(f"{req.label}starting", total=sum(s.duration_s for s in steps))
        taken = [0.0, 0.0]  # rig seconds the runner has taken, rig seconds shown (never going back)
        what = "segment" if tracking is not None else "step"

        def on_progress(index: int, freq: float, waited: float) -> None:
            taken[0] += waited
            done, desc = taken[0], f"{req.label}{step_name(index, len(steps), what)}  {round(freq, 1):g} Hz"
            ahead = rig.computed_ahead() if isinstance(rig, ReportsComputedAhead) else None
            if ahead is not None and ahead[0] > done:  # parallel parts computed further: count all their work
                done, desc = ahead[0], f"{req.label}{min(ahead[1], len(steps))}/{len(steps)} steps computed"
            taken[1] = done = max(done, taken[1])
            with contextlib.suppress(OSError):  # a hung-up terminal (SIGHUP) must not end the run's shutdown
                progress.update(task, completed=done, description=desc)

        # Batches are ~10 per second of wall time: on a sim running 10-20x faster than real time, 1 s rig-time polls
        # (each poll's HDF5 appends and flush cost ~10 ms; the data do not depend on the poll: the sim clock advances
        # the physics in its own chunks of at most 0.5 s either way).
        poll_s = 1.0 if backend_info(backend).simulated_clock and not req.realtime else 0.1
        runner: Runner = (
            tracking.runner(rig, hub, steps, on_progress, stop)
            if tracking is not None
            else Runner(
                rig,
                hub,
                steps,
                checked.limits,
                poll_s=poll_s,
                on_progress=on_progress,
                monitors=[*monitors],
                max_pause_s=protocol.monitors.max_pause_s,
                stop=stop,
            )
        )
        result = runner.run()
    _after_run(rig, path, result, hub, writer.label, model_warnings)
    return result


def _after_run(rig: Rig, path: Path, result: RunResult, hub: Hub, label: str, model_warnings: list[str]) -> None:
    """What the rig reports once the run is over goes into /general; every warning the run gave goes into the
    result (the command says them) and, when the run did not fail, into the session (report banners)."""
    if isinstance(rig, ReportsAfterRun) and result.status != "failed":
        extra = rig.after_run()
        if extra:
            try:
                append_general(path, extra)
            except OSError as exc:
                hub.errors.append(f"{label}: /general not completed ({exc.strerror or exc})")
    # the model's own word on what it cannot stand for (e.g. folding legs; a scene built at the first step says
    # it only now), then what else went wrong
    result.warnings += rig.model_warnings() if isinstance(rig, WarnsOfModel) else []
    result.warnings += hub.errors
    if result.warnings != model_warnings and result.status != "failed":
        with contextlib.suppress(OSError):  # the session is as written; the command still says the warnings
            append_general(path, {"warnings": result.warnings})


@contextlib.contextmanager
def _progress(show: bool) -> Iterator[LogProgress]:
    """The run's progress bar on stderr; a terminal gone (SIGHUP: writes fail with EIO) only ends the bar."""
    progress = LogProgress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:.0f}/{task.total:.0f} s rig time"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=stderr_console(),  # progress is chatter: stdout carries only the command's result
        disable=not show,
        transient=False,
    )
    with contextlib.suppress(OSError):
        progress.start()
    try:
        yield progress
    finally:
        with contextlib.suppress(OSError):
            progress.stop()


def _unreserve(path: Path | None) -> None:
    """Remove a recording reserved by :func:`_reserve` that is still empty (the run did not start)."""
    with contextlib.suppress(OSError):
        if path is not None and not path.is_symlink() and path.is_file() and path.stat().st_size == 0:
            path.unlink()


def _reserve(path: Path) -> None:
    """Create ``path`` empty and exclusively (the recording fills it later): never overwrite a recording."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
    except FileExistsError:
        raise SessionFileError(f"{path}: a recording of that name exists; it is never overwritten") from None
    except OSError as exc:
        raise SessionFileError(f"{path}: cannot create the recording ({exc.strerror or exc})") from None
