"""``beambench run PROTOCOL`` and ``beambench view SESSION``: record a session, replay it into Rerun."""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from beambench.acquisition.protocol.schema import BACKENDS, Backend
from beambench.commands import EXIT_FAULT, EXIT_OK, EXIT_SINK, EXIT_STOPPED, STANDALONE, fail
from beambench.common.resources import shipped_names
from beambench.common.yaml_config import ConfigError
from beambench.sinks.viewer import RerunMode

if TYPE_CHECKING:
    from beambench.acquisition.protocol.schema import Protocol
    from beambench.session.checks import Validated
    from beambench.sim.selection import Plan


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or sys.platform in ("darwin", "win32")


def default_rerun_mode() -> RerunMode:
    """``run``'s live view: the viewer where there is a display, else none (the session holds every sample;
    ``beambench view`` replays it, ``--rerun save`` writes an ``.rrd``: about twice the session's size)."""
    return "spawn" if has_display() else "off"


NO_VIEW_NOTE = (
    "no display: no live view (beambench view SESSION.h5 replays the session; --rerun save writes an .rrd, "
    "about 10 MB a minute of contact sweep)"
)


def resolve_protocol(given: Path, what: str = "run") -> Path:
    """``given`` if it is a file; else the shipped protocol of that name (``contact_sweep`` or
    ``protocols/contact_sweep.yaml`` from any folder); else one line naming the shipped protocols, exit 2 (or the
    ``what`` interrupted line, exit 3, if a stop signal came meanwhile)."""
    from beambench.common.resources import ShippedFileError, resolve_file

    try:
        return resolve_file("protocol", given)
    except ShippedFileError as exc:
        _end_if_stopped(what)  # stopped meanwhile: that, not the bad input, ends it
        fail(str(exc))


_PROTOCOL_HELP = f"Protocol YAML, or the name of a shipped protocol: {shipped_names('protocol')}."


def run(
    protocol_file: Path = typer.Argument(
        ...,
        metavar="PROTOCOL",
        help=_PROTOCOL_HELP,
    ),
    backend: Backend | None = typer.Option(
        None, "--backend", "-b", help="Where to run (default: the protocol's backend, else sim)."
    ),
    out: Path = typer.Option(Path("data"), "--out", "-o", metavar="DIR", help="Folder for the session files."),
    name: str | None = typer.Option(
        None, "--name", "-n", metavar="NAME", help="Session name (default: the protocol's output.name template)."
    ),
    rerun: RerunMode | None = typer.Option(
        None,
        "--rerun",
        help="Live view: spawn a viewer, connect to one, save an .rrd beside the session (about 10 MB a minute), "
        "or off (default: spawn with a display, else off; `beambench view` replays any session later).",
    ),
    realtime: bool = typer.Option(False, "--realtime", help="Pace the simulation to the wall clock."),
    dry_run: bool = typer.Option(
        False, "--dry-run", help="Print the steps, duration, expected run time and limits; move nothing."
    ),
    rig_file: Path | None = typer.Option(
        None,
        "--rig",
        metavar="RIG.yaml",
        help="Rig wiring YAML for emulated/hardware (default: the shipped calibration/rig.yaml).",
    ),
    can_log: Path | None = typer.Option(
        None, "--can-log", metavar="FILE", help="Record all CAN traffic to this .asc or .blf file (ODrive over CAN)."
    ),
    scheduler: str | None = typer.Option(
        None,
        "--scheduler",
        metavar="ADDRESS",
        help="Compute a segmented sim sweep's later parts (sim.segments > 1) on a Dask cluster: its scheduler "
        "address, tcp://HOST:PORT (needs the 'cluster' extra; default: local threads). Same data.",
    ),
) -> None:
    """Run a frequency sweep: step the motor, record mocap, load cells and motor telemetry to an HDF5 session.

    Progress goes to stderr. Standard output carries only the result: with --rerun save the .rrd path, then the
    session path (<out>/<name>.h5) last, so S=$(beambench run … | tail -n1) captures the session. Limits are
    checked before anything moves. Ctrl-C, SIGTERM, SIGHUP (a closed terminal), SIGQUIT and the other stop
    signals idle the motor and close the file cleanly (exit 3); a full disk idles the motor too (exit 4).
    """
    from beambench.acquisition.protocol.plan import session_path
    from beambench.acquisition.protocol.schema import load_protocol
    from beambench.session.checks import validate

    what = "dry run" if dry_run else "run"  # a stop before either starts ends it with one line (_end_if_stopped)
    protocol_file = resolve_protocol(protocol_file, what)
    try:
        protocol, text = load_protocol(protocol_file)
        chosen: Backend = backend or protocol.backend
        if chosen not in BACKENDS:  # typer checks the flag; this guards a bad protocol value
            raise ConfigError("<cli>", "--backend", chosen, f"must be one of {', '.join(BACKENDS)}")
        checked = validate(protocol, chosen, str(protocol_file), can_log)  # every field, dry run included
        if scheduler is not None:
            check_scheduler(scheduler, chosen, protocol)
        from_protocol = rig_file is None and protocol.rig_file is not None
        rig_file = rig_file or protocol_rig_file(protocol, protocol_file)  # --rig, else the protocol's rig_file
        if rig_file is not None:  # every input file too: kind, size, fields
            from beambench.backends.hardware import load_wiring

            try:
                load_wiring(rig_file)
            except ConfigError as exc:
                if not from_protocol:
                    raise
                raise ConfigError(f"{protocol_file}: rig_file: {exc}") from None
        mode: RerunMode = rerun or default_rerun_mode()
        if dry_run:
            _dry_run(protocol, chosen, checked, realtime)
            return
        path = session_path(protocol, chosen, out, name)
    except ConfigError as exc:
        _end_if_stopped(what)  # the user stopped it while it was being checked: that, not the bad input, ends it
        fail(str(exc))
    from beambench.session.run import RigStartError, RunRequest, run_request

    if rerun is None and mode == "off":
        typer.echo(f"beambench: note: {NO_VIEW_NOTE}", err=True)
    request = RunRequest(
        protocol, text, chosen, path, mode, realtime, rig_file, can_log, validated=checked, scheduler=scheduler
    )
    try:
        # the run is over: a late signal must not kill the process before its result (the real command only)
        result = run_request(request, then_ignore_signals=STANDALONE["process"])
    except ConfigError as exc:
        fail(str(exc))
    except RigStartError as exc:
        fail(f"{exc} (motor idled; no session written)", EXIT_FAULT)
    except MemoryError:  # outside the runner (opening, closing): the rig's close has idled the motor
        fail("run error: out of memory (MemoryError) (motor idled)", EXIT_FAULT)
    report_run(result.status, result.message, path, mode == "save", result.warnings, result.idle)


def _dry_run(protocol: Protocol, backend: Backend, checked: Validated, realtime: bool) -> None:
    """The plan, the expected run time and the limits on stdout; a stop signal held since the command line started
    ends it instead, before or after the printing (:func:`_end_if_stopped`)."""
    from beambench.acquisition.protocol.plan import summary

    sim_plan = checked.slices.sim.plan if checked.slices.sim is not None else None
    expected = expected_run_time(protocol, backend, sim_plan, realtime)
    _end_if_stopped("dry run")
    print_dry_run(summary(protocol, backend), expected)
    _end_if_stopped("dry run")


def _end_if_stopped(what: str) -> None:
    """A stop signal the command line held (:mod:`beambench.common.early_signals`: one that came while it imported,
    or while this command checked its inputs) ends the command here, before the run would take it: one line and
    the interrupted exit code. The run itself takes what is still held when it starts (the session records it)."""
    from beambench.acquisition.stop_signals import StopSignal
    from beambench.common import early_signals

    got = early_signals.take()
    if not got:
        return
    stop = StopSignal()
    for signum in got:
        stop.request(signum)
    with contextlib.suppress(OSError):  # a closed terminal (SIGHUP) cannot take it: the exit code still tells
        typer.echo(f"beambench: {what} interrupted: {stop.reason} (nothing moved; no session written)", err=True)
    raise typer.Exit(EXIT_STOPPED)


def check_scheduler(scheduler: str, backend: Backend, protocol: Protocol) -> None:
    """``--scheduler`` computes a segmented sweep's later parts: the sim backend, ``sim.segments`` > 1, a sweep
    computed ahead (not ``track:``), not paced to the wall clock; otherwise a ConfigError naming it."""
    from beambench.acquisition.protocol.backends import backend_info

    if not backend_info(backend).simulated_clock:
        why = f"the {backend} backend runs in real time; --scheduler computes a sim sweep's segments"
    elif protocol.sim.segments < 2:
        why = "the sweep runs in one piece (sim.segments: 1); --scheduler computes its later segments"
    elif protocol.track is not None:
        why = "a track: run computes nothing ahead; --scheduler computes a sweep's later segments"
    else:
        return
    raise ConfigError("<cli>", "--scheduler", scheduler, why)


def protocol_rig_file(protocol: Protocol, protocol_file: Path) -> Path | None:
    """The protocol's ``rig_file:`` (a relative path is taken from the protocol's folder), used when ``--rig`` is
    not given; it is read and checked like ``--rig``."""
    if not protocol.rig_file:
        return None
    given = Path(protocol.rig_file).expanduser()
    return given if given.is_absolute() else protocol_file.parent / given


RUN_EXIT_CODES = {"completed": EXIT_OK, "interrupted": EXIT_STOPPED, "failed": EXIT_SINK}


def report_run(
    status: str, message: str, path: Path, rrd: bool, warnings: list[str] | None = None, idle: str = "motor idled"
) -> None:
    """The result on stdout (the .rrd, then the session), one line on stderr unless completed (with what else
    failed, e.g. the recording on the same full disk), the exit code. A completed run's warnings are a line each.
    A terminal that hung up (SIGHUP) or a closed pipe cannot take them: then only the exit code tells."""
    from beambench.common.text import printable

    # a fault or warning may quote what a device sent (an MCU's error line): no control sequences reach the terminal
    warnings = [printable(w, None) for w in warnings or []]
    message = printable(message, None)
    with contextlib.suppress(OSError):
        if rrd:
            typer.echo(str(path.with_suffix(".rrd")))
        typer.echo(str(path))
    if status == "completed":
        for warning in warnings:
            with contextlib.suppress(OSError):
                typer.echo(f"beambench: warning: {warning}", err=True)
        return
    saved = "the session holds what was written before" if status == "failed" else "session saved"
    also = "".join(f"; also {w}" for w in warnings)
    with contextlib.suppress(OSError):
        typer.echo(f"beambench: run {status}: {message} ({idle}; {saved}){also}", err=True)
    raise typer.Exit(RUN_EXIT_CODES.get(status, EXIT_FAULT))


def expected_run_time(protocol: Protocol, backend: str, sim_plan: Plan | None, realtime: bool = False) -> str:
    """How long the run will take here, in words. A ``track:`` protocol with ``map: twin`` runs in two phases, both
    counted: its sweep on the sim first (the speed map, written beside the session), then the profile.
    ``sim_plan``: the measured timing table's plan of ``protocol`` on the sim (from its validation), if any."""
    if protocol.track is None or protocol.track.map != "twin":
        return _phase_time(protocol, backend, sim_plan, realtime)[1]
    from beambench.acquisition.protocol.plan import plan
    from beambench.session.estimate import SESSION_BYTES_PER_RIG_S
    from beambench.session.slices import sim_slice
    from beambench.session.track_map import map_sweep

    sweep, _ = map_sweep(protocol)
    sweep_steps, profile_steps = plan(sweep), plan(protocol)
    sweep_rig_s = sum(s.duration_s for s in sweep_steps)
    try:
        sweep_plan = sim_slice(sweep).plan
    except ConfigError:
        sweep_plan = None
    map_s, map_how = _phase_time(sweep, "sim", sweep_plan, False)
    profile_s, profile_how = _phase_time(protocol, backend, sim_plan, realtime)
    total = "" if map_s is None or profile_s is None else f"{_about(map_s + profile_s)} in two phases:"
    return (
        f"{total}\n  1. the speed map (track.map: twin): this protocol's sweep on the sim, {len(sweep_steps)} steps, "
        f"{sweep_rig_s:g} s of rig time: {map_how}; written to <session>_map.h5 beside the session "
        f"(about {sweep_rig_s * SESSION_BYTES_PER_RIG_S / 1e6:.0f} MB), kept, not reused by the next run "
        "(track.map: <that file> reuses it)"
        f"\n  2. the profile: {len(profile_steps)} segments, {sum(s.duration_s for s in profile_steps):g} s of rig "
        f"time on the {backend} backend: {profile_how}"
    )


def _phase_time(
    protocol: Protocol, backend: str, sim_plan: Plan | None, realtime: bool = False
) -> tuple[float | None, str]:
    """(seconds or None, in words) for one run: real time on emulated and hardware (and the sim with --realtime);
    on the sim, the stepping time from the measured timing table where the rig has one (``sim_plan``), else from
    the measured stepping costs (``sim_backend/step_costs.csv``); neither loads MuJoCo."""
    from beambench.acquisition.protocol.backends import backend_info
    from beambench.acquisition.protocol.plan import plan

    steps = plan(protocol)
    total = sum(s.duration_s for s in steps)
    if not backend_info(backend).simulated_clock or realtime:
        return total, f"{_duration(total)} (real time on the {backend} backend{' with --realtime' if realtime else ''})"
    if sim_plan is None:  # no measured timing table for this rig: the measured stepping costs (no MuJoCo here)
        from beambench.common.errors import BeambenchError
        from beambench.session.estimate import COSTS_FILE, cost_key, table_run_time
        from beambench.session.slices import sim_slice

        try:
            sim = sim_slice(protocol)
        except BeambenchError as exc:  # the run itself would say so; the dry run still prints its plan
            return None, f"not estimated ({exc})"
        est = table_run_time(protocol, sim)
        if est is None:
            key = ", ".join(f"{k} {v}" for k, v in cost_key(sim).items())
            return None, (
                f"not estimated (no measured stepping cost for {key} in {COSTS_FILE.name}: "
                "`python benchmarks/bench_step_costs.py --ship PROTOCOL` measures it)"
            )
        parts = f"; {est.parallel} segments in parallel" if est.parallel > 1 else ""
        other = f", measured with params {est.params}" if est.params != sim.params else ""
        warn = "".join(f"\nwarning: {w}" for w in est.warnings)
        return est.seconds, (
            f"{_about(est.seconds)} of stepping ({sim.model}; {est.cpu_per_s * 1e3:.0f} ms of CPU per simulated "
            f"second at {est.at_hz:g} Hz from the measured cost table {COSTS_FILE.name}{other}, on the machine that "
            f"measured it{parts}), plus recording overhead{warn}"
        )
    wall = sum(s.duration_s / 10.0 * sim_plan.wall_s_per_10s[s.frequency_hz] for s in steps)
    return wall, (
        f"{_about(wall)} of stepping ({sim_plan.model}, {sim_plan.integrator}; from the measured timing "
        f"table {sim_plan.table}, on the machine that measured it), plus recording overhead"
    )


def _duration(seconds: float) -> str:
    """A time in words: "under 1 s", "12 s", "2.5 min"."""
    if seconds < 1:
        return "under 1 s"
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.1f} min"


def _about(seconds: float) -> str:
    """An estimated time in words: "under 1 s", "about 12 s", "about 2.5 min"."""
    return _duration(seconds) if seconds < 1 else f"about {_duration(seconds)}"


def print_dry_run(s: dict, expected: str) -> None:
    from rich.console import Console
    from rich.table import Table

    from beambench.acquisition.protocol.scenes import scene_info

    t = Table(title=f"Dry run: {s['protocol']} on the {s['rig']} rig ({s['backend']} backend) — nothing moves")
    t.add_column("step", justify="right")
    targets = s.get("targets_mm_s")
    if targets:  # track: the controller picks the frequencies from the map during the run
        t.add_column("target speed (mm/s)", justify="right")
        for i, v in enumerate(targets):
            t.add_row(str(i), f"{v:+g}")
    else:
        t.add_column("frequency (Hz)", justify="right")
        t.add_column("settle + record (s)", justify="right")
        for i, f in enumerate(s["frequencies_hz"]):
            t.add_row(str(i), f"{f:g}", f"{s['settle_s']:g} + {s['record_s']:g}")
    con = Console(soft_wrap=True)  # the dry run's table is its result: stdout
    con.print(t)
    lim = s["limits"]
    if not scene_info(s["rig"]).driven:  # the release test drives nothing: its load is what it is about
        drive = f"no drive: a {s['release_load_g']:g} g tip load released"
    elif targets:
        drive = f"max frequency: chosen by the speed controller, <= {lim['max_frequency_hz']:g} Hz   "
        drive += f"amplitude: {s['amplitude_mm']:g} mm"
    else:
        drive = f"max frequency: {s['max_frequency_hz']:g} Hz   amplitude: {s['amplitude_mm']:g} mm"
    con.print(
        f"steps: {s['steps']}   total duration: {s['total_duration_s']:g} s of rig time   {drive}\n"
        f"expected run time here: {expected}\n"
        f"limits: max_frequency_hz={lim['max_frequency_hz']:g}  max_current_a={lim['max_current_a']:g}  "
        f"max_amplitude_mm={lim['max_amplitude_mm']:g}"
    )


def view(
    session: Path = typer.Argument(..., metavar="SESSION.h5", help="A session file written by `beambench run`."),
    rerun: RerunMode | None = typer.Option(
        None,
        "--rerun",
        help="spawn a viewer, connect to one, or save an .rrd (default: spawn with a display, else save).",
    ),
    out: Path | None = typer.Option(
        None,
        "--out",
        metavar="FILE.rrd",
        help="With --rerun save or --screenshot: the .rrd to write (default with save: <session>_view.rrd beside "
        "the session, numbered if taken; with --screenshot: a temporary one). An existing file is never overwritten.",
    ),
    screenshot: Path | None = typer.Option(
        None,
        "--screenshot",
        metavar="FILE.png",
        help="Save a picture of the real Rerun viewer showing the session (headless: no display needed, but a "
        "Vulkan driver, e.g. Mesa's: apt-get install mesa-vulkan-drivers libvulkan1).",
    ),
    at: float | None = typer.Option(
        None, "--at", metavar="SECONDS", help="With --screenshot: the session time shown (default: the end of step 0)."
    ),
) -> None:
    """Replay a recorded session into the Rerun viewer (or into an .rrd file, whose path is printed), or save a
    picture of the viewer showing it (--screenshot)."""
    if not session.is_file():
        fail(f"{session}: no such session file")
    if screenshot is not None:
        _screenshot(session, screenshot, at, out)
        return
    if at is not None:
        fail("--at needs --screenshot")
    mode = rerun or ("spawn" if has_display() else "save")  # asked to view: without a display, a file
    if mode == "off":
        fail("--rerun = 'off': view needs spawn, connect or save")
    rrd = None
    if mode == "save":
        rrd = out or free_path(session.with_name(f"{session.stem}_view.rrd"))
        if rrd.exists():
            fail(f"{rrd}: exists; give another --out (view never overwrites a recording)")
        check_writable(rrd, "--out")
    from beambench.session.replay import replay_session
    from beambench.sinks.session_file.reader import SessionFileError
    from beambench.sinks.viewer.sink import RecordingNotFinished

    try:
        written = replay_session(session, mode, rrd)
    except SessionFileError as exc:  # already one line naming the file
        fail(str(exc))
    except RecordingNotFinished as exc:  # a full disk under the .rrd: the process then ends past Rerun's exit hooks
        fail(f"{exc.label}: {exc}", EXIT_SINK)
    except OSError as exc:
        fail(f"{session}: cannot read session ({exc})")
    if written is not None:
        typer.echo(str(written))


def _screenshot(session: Path, png: Path, at: float | None, rrd: Path | None) -> None:
    """``view --screenshot``: the picture's path on stdout, or one line saying what is missing."""
    from beambench.session.viewer import ViewerUnavailable, session_screenshot
    from beambench.sinks.session_file.reader import SessionFileError
    from beambench.sinks.viewer.sink import RecordingNotFinished

    if png.suffix.lower() != ".png":
        fail(f"{png}: --screenshot writes a PNG (give FILE.png)")
    if not png.parent.is_dir():
        fail(f"{png.parent}: no such folder for the screenshot")
    if rrd is not None and rrd.exists():
        fail(f"{rrd}: exists; give another --out (view never overwrites a recording)")
    from beambench.common.outputs import output_file_problem

    problem = output_file_problem(png)  # a picture may be replaced, never written through a link or into a device
    if problem:
        fail(f"--screenshot: {problem}")
    for path, option in ((png, "--screenshot"), (rrd, "--out")):
        if path is not None and not path.exists():
            check_writable(path, option)
    try:
        shown = session_screenshot(session, png, at, rrd)
    except ViewerUnavailable as exc:
        fail(f"cannot take a screenshot: {exc}")
    except RecordingNotFinished as exc:  # the replay's .rrd (--out, else a temporary one) on a full disk
        fail(f"cannot take a screenshot: {exc.label}: {exc}", EXIT_SINK)
    except ValueError as exc:
        fail(str(exc))
    except SessionFileError as exc:  # already one line naming the file
        fail(str(exc))
    except OSError as exc:
        fail(f"{session}: cannot read session ({exc})")
    typer.echo(f"viewer at {shown:g} s of {session.name}", err=True)
    typer.echo(str(png))


def check_writable(path: Path, option: str) -> None:
    """One line and exit 2 unless a new file can be created at ``path`` (its folder exists and takes files): a
    probe file is created exclusively and removed at once, before any work."""
    if not path.parent.is_dir():
        fail(f"{option} = {str(path)!r}: no such folder {str(path.parent)!r}")
    try:
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
    except OSError as exc:
        fail(f"{option} = {str(path)!r}: cannot write there ({exc.strerror or exc})")
    with contextlib.suppress(OSError):
        path.unlink()


def free_path(path: Path) -> Path:
    """``path``, or ``<stem>_1<suffix>``, ``_2`` … whichever does not exist yet."""
    k, candidate = 1, path
    while candidate.exists() or candidate.is_symlink():  # a link, even a dangling one, is a taken name
        candidate = path.with_name(f"{path.stem}_{k}{path.suffix}")
        k += 1
    return candidate


def register(app: typer.Typer) -> None:
    app.command("run")(run)
    app.command("view")(view)
