"""``beambench calibrate loadcells``: the load-cell calibration procedure on a terminal, then save.

The procedure (tare, known loads, fit, the tables it prints) is :mod:`beambench.devices.loadcell.calibrate`; this
module reads the options, finds the port (``--port``, the rig file, or an emulated MCU with ``--emulate``), turns
questions into prompts (or, with ``--yes`` and known loads, into notes) and saves the result.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from beambench.commands import fail, sub_app
from beambench.commands.calibrate_sim import register_sim
from beambench.devices.loadcell.calibrate import (
    EMULATE_LOADS,
    CalibrationAborted,
    emulated_plate,
    parse_loads,
    walkthrough,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    from rich.console import Console

    from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration
    from beambench.devices.loadcell.emulated_mcu import EmulatedLoadCellMCU

__all__ = ["loadcells", "register"]

OUT_NAME = "loadcells.yaml"  # in the per-user folder's calibration/ (beambench.common.resources.user_dir)
EMULATE_OUT_NAME = "loadcells-emulated.yaml"


def default_out(emulate: bool, calibration_name: str = OUT_NAME) -> Path:
    """Where a calibration is saved without ``--out``: the per-user folder, never the checkout or the package."""
    from beambench.common.resources import user_dir

    return user_dir("calibration") / (EMULATE_OUT_NAME if emulate else Path(calibration_name).name)


def loadcells(
    port: str | None = typer.Option(
        None, "--port", metavar="DEVICE", help="Serial port of the load-cell MCU (default: from --rig)."
    ),
    baudrate: int | None = typer.Option(None, "--baud", help="Baud rate (default: from --rig, else 921600)."),
    rig: Path | None = typer.Option(
        None,
        "--rig",
        metavar="RIG.yaml",
        help="Rig wiring YAML read for the port when --port is not given (default: the shipped rig.yaml).",
    ),
    out: Path | None = typer.Option(
        None,
        "--out",
        metavar="FILE.yaml",
        help=f"Where to save (default: calibration/{OUT_NAME} in the per-user folder, "
        f"calibration/{EMULATE_OUT_NAME} with --emulate; see docs/commands.md, 'Where files go').",
    ),
    loads: list[str] = typer.Option(
        [],
        "--loads",
        "-l",
        metavar="FN,FT",
        help="Known load FN,FT in N; repeat or space-separate. Asked interactively if omitted.",
    ),
    duration: float = typer.Option(1.0, "--duration", help="Seconds recorded per step (at least 0.05)."),
    settle: float = typer.Option(0.5, "--settle", help="Seconds waited after Enter before recording."),
    emulate: bool = typer.Option(
        False,
        "--emulate",
        help=f"Demo against an emulated MCU on a pty (loads applied for you); saves {EMULATE_OUT_NAME}, not "
        f"{OUT_NAME}, so a demo never replaces the lab's calibration.",
    ),
    yes: bool = typer.Option(
        False,
        "--yes",
        "-y",
        help="No questions: save without asking and, with --loads (or --emulate), record each step after --settle "
        "seconds instead of waiting for Enter. Reads nothing from standard input.",
    ),
) -> None:
    """Walk through a load-cell calibration: tare (per channel), known loads, least-squares 2×4 matrix, save.

    The result is saved to --out, or else in the per-user folder as calibration/loadcells.yaml (with --emulate:
    calibration/loadcells-emulated.yaml); the package's shipped calibration is never changed.
    """
    from beambench.acquisition.capabilities import DeviceFault
    from beambench.common.console import stderr_console
    from beambench.devices.loadcell.driver import DEFAULT_BAUDRATE, SerialLoadCells

    try:
        load_list = parse_loads(loads) or None
    except ValueError as exc:
        fail(str(exc))
    if not duration >= 0.05 or not settle >= 0:
        fail(f"--duration must be >= 0.05 s and --settle >= 0 s (got {duration:g}, {settle:g})")
    if emulate and port:
        fail("--emulate and --port exclude each other")
    if emulate and load_list is None:
        load_list = list(EMULATE_LOADS)
    if not emulate and port is None:
        port, baudrate, out = _wired_port(rig, baudrate, out)
    out = out or default_out(emulate)
    _check_out(out)  # before the operator applies a single load
    console = stderr_console()
    ask = _asker(console, unattended=yes and load_list is not None)
    mcu = _emulated_mcu(console) if emulate else None
    if mcu is not None:
        port = mcu.port
    assert port is not None
    # a calibration averages the frames it receives in each window: lost frames (a loaded machine's reader falling
    # behind while a prompt waits) are counted and said in the link line below, never a fault that loses the walk
    stream = SerialLoadCells(port, baudrate or DEFAULT_BAUDRATE, max_lost_fraction=None)
    try:
        stream.start()
        if mcu is not None:
            mcu.start()
        source = (
            f"beambench calibrate loadcells, {datetime.now(UTC).isoformat(timespec='seconds')}, "
            f"port {'emulated' if emulate else port}"
        )
        on_step = _follow_steps(mcu) if mcu is not None else None
        cal, fit = walkthrough(
            stream, load_list, ask, console, settle_s=settle, duration_s=duration, on_step=on_step, source=source
        )
        cal.source += f", {len(fit.loads)} loads, RMS residual Fn {fit.rms[0]:.4g} N Ft {fit.rms[1]:.4g} N"
        st = stream.stats()
        console.print(
            f"[dim]link: {st['frames']} frames, {st['crc_errors']} CRC errors, {st['lost_frames']} lost[/dim]"
        )
        if yes or _confirm_save(console, out):
            _save(cal, out, console)
    except (CalibrationAborted, DeviceFault) as exc:
        fail(str(exc))
    finally:
        stream.stop()
        if mcu is not None:
            mcu.close()


def _wired_port(rig: Path | None, baudrate: int | None, out: Path | None) -> tuple[str, int, Path]:
    """The port, baud rate and default output of the rig file (``--rig``, else the shipped ``rig.yaml``)."""
    from beambench.backends.hardware import DEFAULT_RIG_FILE, load_wiring
    from beambench.common.yaml_config import ConfigError

    if rig is None:
        rig = DEFAULT_RIG_FILE
    if not rig.exists():
        fail(f"no --port given and no rig file at {rig}")
    try:
        wiring = load_wiring(rig)
    except ConfigError as exc:
        fail(str(exc))
    return (
        wiring.loadcell.port,
        baudrate or wiring.loadcell.baudrate,
        out or default_out(False, wiring.loadcell_calibration),
    )


def _asker(console: Console, unattended: bool) -> Callable[[str], str]:
    """A prompt on stdin; ``unattended`` (``--yes`` with known loads): print the step and go on."""
    from rich.prompt import Prompt

    def ask(text: str) -> str:
        if unattended:  # say what happens, then go on without reading stdin
            console.print(f"[dim]{text.split(', then press Enter')[0]}[/dim]", soft_wrap=True)
            return ""
        try:
            return Prompt.ask(text, console=console, default="", show_default=False)
        except (EOFError, KeyboardInterrupt):
            raise CalibrationAborted("calibration aborted: no answer on stdin") from None

    return ask


def _emulated_mcu(console: Console) -> EmulatedLoadCellMCU:
    """An emulated MCU on a pty, with a plate unlike the shipped calibration (``--emulate``)."""
    from beambench.devices.loadcell.emulated_mcu import EmulatedLoadCellMCU

    mcu = EmulatedLoadCellMCU(calibration=emulated_plate(), noise_counts=40.0, seed=1)
    port = mcu.open()
    console.print(f"[dim]emulated load-cell MCU on {port}; loads are applied for you[/dim]")
    return mcu


def _follow_steps(mcu: EmulatedLoadCellMCU) -> Callable[[tuple[float, float]], int | None]:
    """The emulated plate carries each step's load; returns the first frame that carries it."""

    def apply_load(load: tuple[float, float]) -> int | None:
        return mcu.switch_force((float(load[0]), float(load[1])))

    return apply_load


def _confirm_save(console: Console, out: Path) -> bool:
    from rich.prompt import Confirm

    try:
        save = Confirm.ask(f"Save to {out}?", console=console, default=True)
    except (EOFError, KeyboardInterrupt):
        raise CalibrationAborted("calibration aborted: no answer on stdin") from None
    if not save:
        console.print("not saved", soft_wrap=True)
    return save


def _check_out(out: Path) -> None:
    """One line and exit 2 unless the calibration can be saved at ``out`` (a regular file or a new one, not a link,
    in a folder that takes it), probed before any load is asked for."""
    from beambench.common.outputs import output_file_problem

    problem = output_file_problem(out)
    if problem:
        fail(f"--out = {str(out)!r}: {problem.removeprefix(f'{out}: ')}")


def _save(cal: LoadCellCalibration, out: Path, console: Console) -> None:
    """Save to ``out``; if that still fails (the disk filled meanwhile), the calibration goes to stdout as the
    YAML it would have saved, so the measured matrix is not lost, and the command fails (exit 1)."""
    from beambench.common.outputs import output_file_problem

    try:
        problem = output_file_problem(out)  # checked again: the place may have changed during the walk
        if problem:
            raise OSError(problem)
        out.parent.mkdir(parents=True, exist_ok=True)
        cal.save(out)
    except OSError as exc:
        typer.echo(f"# not saved: the calibration measured (save it as a .yaml file)\n{cal.to_yaml()}", nl=False)
        fail(f"{out}: cannot save calibration ({exc.strerror or exc}); it is printed above", code=1)
    console.print(f"saved {out}", soft_wrap=True)
    typer.echo(str(out))


def register(app: typer.Typer) -> None:
    """Add ``beambench calibrate loadcells``."""
    sub = sub_app(
        "Calibrate the rig's load cells (loadcells) or fit the twin's unknowns to a session or published numbers (sim)."
    )
    sub.command("loadcells")(loadcells)
    register_sim(sub)
    app.add_typer(sub, name="calibrate")
