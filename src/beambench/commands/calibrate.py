"""``beambench calibrate loadcells``: tare, known loads, least-squares fit, residuals, save.

The walkthrough (:func:`walkthrough`) is independent of the terminal: it takes a running load-cell
:class:`~beambench.acquisition.capabilities.Stream`, the loads, an ``ask`` callable (a prompt that returns the answer)
and an optional ``on_step`` hook called when a load should be on the plate; the command wires it to rich
prompts on stdin, and with ``--emulate`` to an emulated MCU on a pty whose force follows the steps.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from beambench.commands import fail, sub_app
from beambench.commands.calibrate_sim import register_sim

if TYPE_CHECKING:
    import numpy as np
    from rich.console import Console

    from beambench.acquisition.calibration import LoadCellCalibration, MatrixFit
    from beambench.acquisition.capabilities import Stream

OUT_NAME = "loadcells.yaml"  # in the per-user folder's calibration/ (beambench.common.resources.user_dir)
EMULATE_OUT_NAME = "loadcells-emulated.yaml"
EMULATE_LOADS = [(1.0, 0.0), (2.0, 0.0), (0.0, 0.5), (0.0, 1.0), (1.5, 0.5), (1.0, -0.5)]


class CalibrationAborted(Exception):
    """The walkthrough cannot go on (no samples, no answer); the message is one line for the user."""


@dataclass
class Recording:
    """Samples recorded for one step: their per-channel mean and standard deviation."""

    samples: np.ndarray

    @property
    def mean(self) -> np.ndarray:
        return self.samples.mean(axis=0)

    @property
    def std(self) -> np.ndarray:
        return self.samples.std(axis=0)


def parse_loads(values: list[str]) -> list[tuple[float, float]]:
    """``["1,0", "0,0.5 2,0"]`` → ``[(1, 0), (0, 0.5), (2, 0)]``; ValueError naming the bad one."""
    loads = []
    for value in values:
        for item in value.replace(";", " ").split():
            parts = item.split(",")
            try:
                if len(parts) != 2:
                    raise ValueError
                loads.append((float(parts[0]), float(parts[1])))
            except ValueError:
                raise ValueError(f"--loads {item!r}: expected FN,FT in newtons, e.g. 1.0,0") from None
    return loads


def _noise_floor(std: np.ndarray) -> float:
    """Noise level used to tell a load from no load: the largest channel std, at least one count."""
    return max(float(std.max()), 1.0)


def record(stream: Stream, settle_s: float, duration_s: float) -> Recording:
    """Wait ``settle_s``, drop what came meanwhile, then collect ``duration_s`` of samples."""
    import numpy as np

    from beambench.acquisition.batch import Batch

    time.sleep(settle_s)
    stream.read()
    batches = []
    t_end = time.monotonic() + duration_s
    while time.monotonic() < t_end:
        time.sleep(min(0.05, max(0.0, t_end - time.monotonic())))
        batches.append(stream.read())
    b = Batch.concat(batches)
    if len(b) == 0:
        raise CalibrationAborted(f"no load-cell samples in {duration_s:g} s: is the MCU connected and running?")
    return Recording(np.asarray(b.columns["data"], dtype=np.float64))


def walkthrough(
    stream: Stream,
    loads: list[tuple[float, float]] | None,
    ask: Callable[[str], str],
    console: Console,
    *,
    settle_s: float = 0.5,
    duration_s: float = 1.0,
    gain: np.ndarray | None = None,
    on_step: Callable[[tuple[float, float]], None] | None = None,
    source: str = "",
) -> tuple[LoadCellCalibration, MatrixFit]:
    """Tare then known loads, fitted. ``loads=None`` asks the user for each load until a blank answer."""
    import numpy as np
    from rich.table import Table

    from beambench.acquisition.calibration import (
        LoadCellCalibration,
        fit_matrix,
        tare_counts,
    )
    from beambench.acquisition.streams import LOADCELL_CHANNELS

    hook = on_step or (lambda load: None)
    hook((0.0, 0.0))
    ask("Remove every load from the plate, then press Enter to record the tare")
    rec = record(stream, settle_s, duration_s)
    tare = tare_counts(rec.samples)
    tare_std = rec.std
    t = Table(title=f"Tare ({len(rec.samples)} samples, mean over time per channel)")
    for col in ("", *LOADCELL_CHANNELS):
        t.add_column(col, justify="right")
    t.add_row("mean [count]", *(f"{v:.1f}" for v in tare))
    t.add_row("std [count]", *(f"{v:.1f}" for v in rec.std))
    console.print(t)

    known: list[tuple[float, float]] = []
    means: list[np.ndarray] = []
    k = 0
    while loads is None or k < len(loads):
        if loads is None:
            answer = ask(f"Known load {k + 1} as FN,FT in N (blank to finish)").strip()
            if not answer:
                break
            try:
                parsed = parse_loads([answer])
                if len(parsed) != 1:
                    raise ValueError(f"{answer!r}: one load at a time, as FN,FT")
            except ValueError as exc:
                console.print(f"[red]{exc}[/red]", soft_wrap=True)
                continue
            load = parsed[0]
        else:
            load = loads[k]
        hook(load)
        ask(f"Apply load {k + 1}: Fn = {load[0]:g} N, Ft = {load[1]:g} N, then press Enter")
        rec = record(stream, settle_s, duration_s)
        known.append(load)
        means.append(rec.mean)
        console.print(f"  load {k + 1}: {len(rec.samples)} samples, std {np.array2string(rec.std, precision=1)} counts")
        k += 1
    hook((0.0, 0.0))
    change = np.abs(np.array(means).reshape(-1, 4) - tare).max(initial=0.0)
    if known and change < 5 * _noise_floor(tare_std):
        raise CalibrationAborted(
            f"the loads changed the counts by at most {change:.0f}, within the noise ({tare_std.max():.0f} std): "
            "are the load cells connected and the weights on the plate?"
        )
    try:
        fit = fit_matrix(np.array(means).reshape(-1, 4), np.array(known).reshape(-1, 2), tare, gain)
    except ValueError as exc:
        raise CalibrationAborted(str(exc)) from None
    g = np.ones(4) if gain is None else np.asarray(gain, float)
    cal = LoadCellCalibration(tare=tare, gain=g, matrix=fit.matrix, sensitivity=fit.sensitivity, source=source)
    _show_fit(console, fit)
    return cal, fit


def _show_fit(console: Console, fit: MatrixFit) -> None:
    from rich.table import Table

    t = Table(title="Known loads and the fit (N)")
    for col in ("#", "Fn", "Ft", "Fn fit", "Ft fit", "ΔFn", "ΔFt"):
        t.add_column(col, justify="right")
    for i, (f, g, r) in enumerate(zip(fit.loads, fit.fitted, fit.residuals)):
        t.add_row(str(i + 1), *(f"{v:.4f}" for v in (*f, *g, *r)))
    console.print(t)
    m = Table(title=f"Matrix N per count (rank {fit.rank} of 4)")
    for col in ("", "lc0", "lc1", "lc2", "lc3"):
        m.add_column(col, justify="right")
    for name, row in zip(("Fn", "Ft"), fit.matrix):
        m.add_row(name, *(f"{v:.4e}" for v in row))
    console.print(m)
    console.print(f"RMS residual: Fn {fit.rms[0]:.4f} N, Ft {fit.rms[1]:.4f} N")


def _emulated_plate():
    """A plate that differs from the shipped calibration (gains off by a few %, crosstalk, other offsets)."""
    import numpy as np

    from beambench.acquisition.calibration import (
        LoadCellCalibration,
        default_calibration,
    )

    nominal = default_calibration()
    rng = np.random.default_rng(7)
    sens = nominal.sensitivity * (1 + 0.05 * rng.standard_normal((4, 1))) + 400.0 * rng.standard_normal((4, 2))
    tare = nominal.tare + rng.normal(0.0, 300.0, 4)
    return LoadCellCalibration(tare=tare, sensitivity=sens, source="emulated plate")


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
        f"calibration/{EMULATE_OUT_NAME} with --emulate; see README, 'Where files go').",
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
        False, "--emulate", help="Demo against an emulated MCU on a pty (loads applied for you)."
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

    The result goes to --out or to the per-user folder; the package's shipped calibration is never changed.
    """
    from rich.console import Console
    from rich.prompt import Confirm, Prompt

    from beambench.acquisition.capabilities import DeviceFault
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
        if rig is None:
            from beambench.backends.hardware import DEFAULT_RIG_FILE

            rig = DEFAULT_RIG_FILE
        if not rig.exists():
            fail(f"no --port given and no rig file at {rig}")
        from beambench.acquisition.config import ConfigError, load_rig_file

        try:
            wiring = load_rig_file(rig)
        except ConfigError as exc:
            fail(str(exc))
        port, baudrate = wiring.loadcell.port, baudrate or wiring.loadcell.baudrate
        out = out or default_out(False, wiring.loadcell_calibration)
    out = out or default_out(emulate)
    console = Console(stderr=True)
    unattended = yes and load_list is not None

    def ask(text: str) -> str:
        if unattended:  # --yes with known loads: say what happens, then go on without reading stdin
            console.print(f"[dim]{text.split(', then press Enter')[0]}[/dim]", soft_wrap=True)
            return ""
        try:
            return Prompt.ask(text, console=console, default="", show_default=False)
        except (EOFError, KeyboardInterrupt):
            raise CalibrationAborted("calibration aborted: no answer on stdin") from None

    mcu = None
    on_step = None
    if emulate:
        from beambench.emulators.loadcell_mcu import EmulatedLoadCellMCU

        mcu = EmulatedLoadCellMCU(calibration=_emulated_plate(), noise_counts=40.0, seed=1)
        port = mcu.open()
        console.print(f"[dim]emulated load-cell MCU on {port}; loads are applied for you[/dim]")

        def apply_load(load: tuple[float, float]) -> None:
            force = (float(load[0]), float(load[1]))
            mcu.set_force(lambda t: force)

        on_step = apply_load

    assert port is not None
    stream = SerialLoadCells(port, baudrate or DEFAULT_BAUDRATE)
    try:
        stream.start()
        if mcu is not None:
            mcu.start()
        source = (
            f"beambench calibrate loadcells, {datetime.now(UTC).isoformat(timespec='seconds')}, "
            f"port {'emulated' if emulate else port}"
        )
        cal, fit = walkthrough(
            stream, load_list, ask, console, settle_s=settle, duration_s=duration, on_step=on_step, source=source
        )
        cal.source += f", {len(fit.loads)} loads, RMS residual Fn {fit.rms[0]:.4g} N Ft {fit.rms[1]:.4g} N"
        st = stream.stats()
        console.print(
            f"[dim]link: {st['frames']} frames, {st['crc_errors']} CRC errors, {st['lost_frames']} lost[/dim]"
        )
        if not yes:
            try:
                save = Confirm.ask(f"Save to {out}?", console=console, default=True)
            except (EOFError, KeyboardInterrupt):
                raise CalibrationAborted("calibration aborted: no answer on stdin") from None
            if not save:
                console.print("not saved", soft_wrap=True)
                return
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            cal.save(out)
        except OSError as exc:
            fail(f"{out}: cannot save calibration ({exc.strerror or exc})")
        console.print(f"saved {out}", soft_wrap=True)
        typer.echo(str(out))
    except (CalibrationAborted, DeviceFault) as exc:
        fail(str(exc))
    finally:
        stream.stop()
        if mcu is not None:
            mcu.close()


def register(app: typer.Typer) -> None:
    """Add ``beambench calibrate loadcells``."""
    sub = sub_app("Calibrate rig sensors.")
    sub.command("loadcells")(loadcells)
    register_sim(sub)
    app.add_typer(sub, name="calibrate")
