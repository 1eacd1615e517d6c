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
        """Ping the ODrive and every device stream of the rig (the mocap server, the load-cell MCU, ...); print version,
        serial and rate. Moves nothing."""
        from rich.console import Console
        from rich.markup import escape
        from rich.table import Table

        from beambench.backends.hardware import DEFAULT_RIG_FILE, load_wiring
        from beambench.common.text import printable
        from beambench.common.yaml_config import ConfigError

        try:
            rig = load_wiring(rig_file or DEFAULT_RIG_FILE) if not emulate else None
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
    """Ping the motor and every registered device stream that can be pinged, each as its rig file
    (:func:`beambench.backends.hardware.load_wiring`) wires it; never raises for a device that is absent."""
    from beambench.devices.odrive import can_ping as odrive_can
    from beambench.devices.streams import DEVICE_STREAMS

    out: dict[str, dict[str, Any]] = {}
    od = rig.odrive
    if od.transport == "can":
        out["motor (ODrive CAN)"] = odrive_can.ping(od.channel, od.interface, od.node_id, bitrate=od.bitrate)
    else:
        from beambench.devices.odrive import usb_motor as odrive_usb

        out["motor (ODrive USB)"] = odrive_usb.ping(od.serial_number)
    for stream in DEVICE_STREAMS.values():
        answer = stream.ask(rig)
        if answer is not None:
            out[stream.label] = answer
    return out
