"""``beambench devices``: ping every device of the rig file and print what answered."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from beambench.commands import EXIT_FAULT, fail


def register(app: typer.Typer) -> None:
    @app.command()
    def devices(
        rig_file: Path | None = typer.Option(
            None,
            "--rig",
            metavar="RIG.yaml",
            help="Rig wiring YAML: addresses, CAN channel, port (default: the shipped rig.yaml).",
        ),
        emulate: bool = typer.Option(False, "--emulate", help="Start the emulated rig on loopback and ping it."),
    ) -> None:
        """Ping the mocap server, the ODrive and the load-cell MCU; print version, serial and rate. Moves nothing."""
        from rich.console import Console
        from rich.markup import escape
        from rich.table import Table

        from beambench.acquisition.protocol.schema import load_rig_file
        from beambench.backends.hardware import DEFAULT_RIG_FILE
        from beambench.common.text import printable
        from beambench.common.yaml_config import ConfigError

        try:
            rig = load_rig_file(rig_file or DEFAULT_RIG_FILE) if not emulate else None
        except ConfigError as exc:
            fail(str(exc))
        if emulate:
            from beambench.backends.emulated import emulated_peers

            with emulated_peers() as wiring:
                results = ping_all(wiring)
        else:
            results = ping_all(rig)
        table = Table(title="Devices")
        for col in ("device", "found", "details"):
            table.add_column(col)
        for name, info in results.items():
            found = bool(info.get("found", False))
            details = ", ".join(  # what a device sent: no escape sequences, no rich markup
                f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={printable(v)}"
                for k, v in info.items()
                if k != "found" and v not in (None, "")
            )
            table.add_row(name, "[green]yes" if found else "[red]no", escape(details))
        Console().print(table)
        if not all(r.get("found") for r in results.values()):
            raise typer.Exit(EXIT_FAULT)


def ping_all(rig: Any) -> dict[str, dict[str, Any]]:
    """Ping each device of a :class:`beambench.acquisition.protocol.schema.RigFile`; never raises for a device that is absent."""
    from beambench.devices.loadcell import driver as loadcell
    from beambench.devices.natnet import client as natnet
    from beambench.devices.odrive import can_ping as odrive_can

    out: dict[str, dict[str, Any]] = {}
    nn = rig.natnet.model_dump(exclude={"markers"})
    try:
        out["mocap (NatNet)"] = {"found": True, **natnet.ping(natnet.NatNetConfig.from_mapping(nn))}
    except Exception as exc:
        out["mocap (NatNet)"] = {"found": False, "error": str(exc)}
    od = rig.odrive
    if od.transport == "can":
        out["motor (ODrive CAN)"] = odrive_can.ping(od.channel, od.interface, od.node_id, bitrate=od.bitrate)
    else:
        from beambench.devices.odrive import usb_motor as odrive_usb

        out["motor (ODrive USB)"] = odrive_usb.ping(od.serial_number)
    try:
        lc = loadcell.ping(rig.loadcell.port, rig.loadcell.baudrate)
        out["load cells (serial)"] = {"found": lc.ok, **{k: v for k, v in vars(lc).items() if k not in ("ok", "stats")}}
    except Exception as exc:
        out["load cells (serial)"] = {"found": False, "error": str(exc)}
    return out
