"""Wire one run together: rig + sinks (HDF5 session, Rerun) + runner with a progress bar."""

from __future__ import annotations

from pathlib import Path

from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from beambench.calibration import default_calibration
from beambench.config import Protocol
from beambench.hub import Batch, Hub, Sink
from beambench.monitors import build_monitors
from beambench.protocol import motor_limits, plan
from beambench.provenance import provenance
from beambench.rigs import build_rig
from beambench.runner import RunResult, Runner
from beambench.store import SessionWriter, append_general, read_session

RerunMode = str  # spawn | connect | save | off (beambench.live is imported only when a viewer is wanted)


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
    options = {"can_log": can_log} if can_log else {}
    rig = build_rig(protocol, backend, realtime=realtime, rig_file=rig_file, **options)
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
        if getattr(rig, "geometry", None):  # the mocap's world axes, which analysis needs (Motive: y up)
            general["geometry"] = dict(rig.geometry)
        sinks: list[Sink] = [SessionWriter(path, general, max_steps=len(steps))]
        monitors = build_monitors(protocol, [s.describe().name for s in rig.streams])
        sinks += monitors
        if rerun_mode != "off":
            from beambench.live import RerunSink

            sinks.append(RerunSink(rerun_mode, path.stem, path.with_suffix(".rrd"), t0_ns=rig.clock.now_ns()))
        hub = Hub(sinks)
        hub.open([s.describe() for s in rig.streams])
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
        runner = Runner(rig, hub, steps, motor_limits(protocol), poll_s=poll_s, on_progress=on_progress,
                        monitors=monitors, max_pause_s=protocol.monitors.max_pause_s)
        result = runner.run()
    post_run = getattr(rig, "post_run", None)
    if post_run:
        append_general(path, post_run)
    for err in hub.errors:
        progress.console.print(f"[yellow]warning: live view stopped: {err}")
    return result


def replay_session(session_path: Path, mode: RerunMode, out: Path | None = None) -> Path | None:
    """Send a recorded session to Rerun in ~1 s batches; returns the .rrd path in save mode."""
    from beambench.live import RerunSink

    session = read_session(session_path)
    rrd = (out or session_path.with_suffix(".rrd")) if mode == "save" else None
    t0 = min((int(s.host_time_ns[0]) for s in session.streams.values() if len(s)), default=0)
    sink = RerunSink(mode, session_path.stem, rrd, t0_ns=t0)
    sink.open([s.spec for s in session.streams.values()])
    for name, s in session.streams.items():
        step = max(1, int(s.spec.rate_hz) or 1000)
        for i in range(0, len(s), step):
            sl = slice(i, i + step)
            sink.write(Batch(name, s.host_time_ns[sl], s.device_time[sl], {k: v[sl] for k, v in s.columns.items()}))
    for row in session.events.itertuples():
        sink.event(int(row.host_time_ns), row.kind, row.message)
    sink.close()
    return rrd
