"""Wire one run together: rig + sinks (HDF5 session, Rerun) + runner with a progress bar."""

from __future__ import annotations

import os
from pathlib import Path
from typing import cast

from rich.progress import (
    BarColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from beambench.acquisition.calibration import default_calibration
from beambench.acquisition.capabilities import HasSilenceTimeouts, ReportsAfterRun
from beambench.acquisition.config import Backend, Protocol
from beambench.acquisition.hub import Hub, Sink
from beambench.acquisition.monitors import build_monitors
from beambench.acquisition.plan import motor_limits, plan
from beambench.acquisition.runner import Runner, RunResult, StopSignal, stop_on_signals
from beambench.backends.build import build_rig
from beambench.common.console import stderr_console
from beambench.session.checks import check_protocol
from beambench.session.provenance import provenance
from beambench.sinks import RerunMode  # rerun itself is imported only when a viewer is wanted
from beambench.sinks.hdf5 import SessionFileError, SessionWriter, append_general


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
    """Run ``protocol`` on ``backend`` and save the session at ``path`` (and ``.rrd`` beside it with save).

    From the first line on, SIGINT and SIGTERM only request a stop (see :mod:`beambench.acquisition.runner`):
    a signal while the rig opens still yields a session that ends ``interrupted`` with the motor idled.
    """
    with stop_on_signals() as stop:
        return _run_session(
            protocol, protocol_text, backend, path, rerun_mode, realtime, rig_file, can_log, show_progress, stop
        )


def _run_session(
    protocol: Protocol,
    protocol_text: str,
    backend: str,
    path: Path,
    rerun_mode: RerunMode,
    realtime: bool,
    rig_file: Path | None,
    can_log: Path | None,
    show_progress: bool,
    stop: StopSignal,
) -> RunResult:
    check_protocol(protocol, "<protocol>", backend, can_log)
    if rerun_mode == "save":
        _reserve(path.with_suffix(".rrd"))
    rig = build_rig(protocol, cast(Backend, backend), realtime=realtime, rig_file=rig_file, can_log=can_log)
    steps = plan(protocol)
    rig.open()
    try:
        general = {
            "protocol": protocol_text,
            "protocol_name": protocol.name,
            "rig": protocol.rig,
            "backend": backend,
            "identity": rig.identity(),
            "calibration": {"loadcells": default_calibration().to_yaml()},
            **provenance(),
        }
        specs = [s.describe() for s in rig.streams]
        frames = [s.frame for s in specs if s.frame is not None]
        if frames:  # the mocap's world axes, which analysis needs (Motive: y up)
            general["geometry"] = frames[0].as_dict()
        writer = SessionWriter(path, general)
        sinks: list[Sink] = [writer]
        silence = rig.silence_timeouts() if isinstance(rig, HasSilenceTimeouts) else None
        monitors = build_monitors(protocol, [s.name for s in specs], silence)
        sinks += monitors
        if rerun_mode != "off":
            from beambench.sinks.rerun_view import RerunSink

            sinks.append(
                RerunSink(
                    rerun_mode,
                    path.stem,
                    path.with_suffix(".rrd"),
                    t0_ns=rig.clock.now_ns(),
                    calibration=default_calibration(),  # the one stored in /general: forces in N live
                    rig=protocol.rig,
                    total_steps=len(steps),
                )
            )
        hub = Hub(sinks, critical=(writer,))
        hub.open(specs)
    except BaseException:
        rig.close()
        raise
    total = sum(s.duration_s for s in steps)
    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:.0f}/{task.total:.0f} s rig time"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=stderr_console(),  # progress is chatter: stdout carries only the command's result
        disable=not show_progress,
        transient=False,
    ) as progress:
        task = progress.add_task("starting", total=total)

        def on_progress(index: int, freq: float, waited: float) -> None:
            progress.update(task, advance=waited, description=f"step {index + 1}/{len(steps)}  {freq:g} Hz")

        # Batches are ~10 per second of wall time: on a sim running 10-20x faster than real time, 1 s rig-time polls
        # (each poll's HDF5 appends and flush cost ~10 ms; the data do not depend on the poll: the sim clock advances
        # the physics in its own chunks of at most 0.5 s either way).
        poll_s = 1.0 if backend == "sim" and not realtime else 0.1
        runner = Runner(
            rig,
            hub,
            steps,
            motor_limits(protocol),
            poll_s=poll_s,
            on_progress=on_progress,
            monitors=[*monitors],
            max_pause_s=protocol.monitors.max_pause_s,
            stop=stop,
        )
        result = runner.run()
    if isinstance(rig, ReportsAfterRun):
        extra = rig.after_run()
        if extra:
            append_general(path, extra)
    for err in hub.errors:
        progress.console.print(f"[yellow]warning: live view stopped: {err}")
    return result


def _reserve(path: Path) -> None:
    """Create ``path`` empty and exclusively (the recording fills it later): never overwrite a recording."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
    except FileExistsError:
        raise SessionFileError(f"{path}: a recording of that name exists; it is never overwritten") from None
    except OSError as exc:
        raise SessionFileError(f"{path}: cannot create the recording ({exc.strerror or exc})") from None
