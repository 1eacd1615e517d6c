"""Wire one run together: rig + sinks (HDF5 session, Rerun) + runner with a progress bar."""

from __future__ import annotations

from pathlib import Path

from rich.progress import (
    BarColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from beambench.acquisition.calibration import default_calibration
from beambench.acquisition.capabilities import ReportsAfterRun
from beambench.acquisition.config import Protocol
from beambench.acquisition.hub import Hub, Sink
from beambench.acquisition.monitors import build_monitors
from beambench.acquisition.plan import motor_limits, plan
from beambench.acquisition.runner import Runner, RunResult
from beambench.rigs.build import build_rig
from beambench.session.provenance import provenance
from beambench.sinks.hdf5 import SessionWriter, append_general

RerunMode = str  # spawn | connect | save | off (beambench.sinks.rerun_view is imported only when a viewer is wanted)


def run_session(
    protocol: Protocol,
    protocol_text: str,
    backend: str,
    path: Path,
    rerun_mode: RerunMode = "off",
    realtime: bool = False,
    rig_file: Path | None = None,
    can_log: Path | None = None,
    show_progress: bool = True,
) -> RunResult:
    """Run ``protocol`` on ``backend`` and save the session at ``path`` (and ``.rrd`` beside it with save)."""
    rig = build_rig(protocol, backend, realtime=realtime, rig_file=rig_file, can_log=can_log)
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
        monitors = build_monitors(protocol, [s.describe().name for s in rig.streams])
        sinks += monitors
        if rerun_mode != "off":
            from beambench.sinks.rerun_view import RerunSink

            sinks.append(RerunSink(rerun_mode, path.stem, path.with_suffix(".rrd"), t0_ns=rig.clock.now_ns()))
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
        disable=not show_progress,
        transient=False,
    ) as progress:
        task = progress.add_task("starting", total=total)

        def on_progress(index: int, freq: float, waited: float) -> None:
            progress.update(task, advance=waited, description=f"step {index + 1}/{len(steps)}  {freq:g} Hz")

        # Batches are ~10 per second of wall time: on a sim running faster than real time, longer rig-time polls.
        poll_s = 0.5 if backend == "sim" and not realtime else 0.1
        runner = Runner(
            rig,
            hub,
            steps,
            motor_limits(protocol),
            poll_s=poll_s,
            on_progress=on_progress,
            monitors=monitors,
            max_pause_s=protocol.monitors.max_pause_s,
        )
        result = runner.run()
    if isinstance(rig, ReportsAfterRun):
        extra = rig.after_run()
        if extra:
            append_general(path, extra)
    for err in hub.errors:
        progress.console.print(f"[yellow]warning: live view stopped: {err}")
    return result
