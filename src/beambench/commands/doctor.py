"""``beambench doctor``: one table of what this machine has for each part, each row with what to do."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from beambench.commands import EXIT_FAULT, fail

STATE_STYLE = {"ok": "[green]ok", "missing": "[red]missing", "advice": "[yellow]advice"}


def register(app: typer.Typer) -> None:
    @app.command()
    def doctor(
        rig_file: Path | None = typer.Option(
            None,
            "--rig",
            metavar="RIG.yaml",
            help="Rig wiring YAML whose devices are checked (default: the shipped rig.yaml).",
        ),
        out: Path = typer.Option(Path("data"), "--out", "-o", metavar="DIR", help="Where sessions go (free disk)."),
        sim: bool = typer.Option(
            False, "--sim", help="This machine runs the simulator only: the rig's devices are shown, not required."
        ),
        min_free_gb: float = typer.Option(2.0, "--min-free-gb", help="Free disk wanted where sessions go (GB)."),
        root: Path = typer.Option(Path("/"), "--root", hidden=True, help="Read /sys and /dev below this folder."),
    ) -> None:
        """Check this machine for each part: the motor's SocketCAN interface and bitrate, the load cells' serial
        port and the permission to open it, the NatNet server, any other registered device stream's device (its
        ping), free disk where sessions go, the Vulkan driver
        and the rerun program of the real viewer, the clock source. Each row says what to do. Exit status 1
        when a required part is missing (the rig file's devices, unless --sim, and the disk)."""
        from rich.console import Console
        from rich.table import Table

        from beambench.backends.hardware import DEFAULT_RIG_FILE, load_wiring
        from beambench.common.console import LOG_WIDTH
        from beambench.common.yaml_config import ConfigError
        from beambench.session.doctor import Machine, check_machine, failed

        if not min_free_gb >= 0:
            fail(f"--min-free-gb {min_free_gb:g}: must be 0 or more")
        try:
            rig = load_wiring(rig_file or DEFAULT_RIG_FILE)
        except ConfigError as exc:
            fail(str(exc))
        rows = check_machine(Machine(rig, out, root, None, sim, min_free_gb))
        table = Table(title="beambench doctor: this machine", show_lines=True)
        for col in ("part", "state", "this machine has", "to do"):
            table.add_column(col, overflow="fold")
        for r in rows:
            need = "" if r.required or r.state == "ok" else " (optional)"
            table.add_row(r.part, STATE_STYLE[r.state] + need, r.found, r.todo)
        Console(width=None if sys.stdout.isatty() else LOG_WIDTH).print(table)  # a log keeps whole lines
        if failed(rows):
            raise typer.Exit(EXIT_FAULT)
