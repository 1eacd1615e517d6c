"""``beambench natnet decode``: NatNet frames out of a Wireshark/tcpdump capture, one CSV row per frame."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from beambench.commands import fail, sub_app

natnet_app = sub_app("OptiTrack Motive (NatNet 3.0/4.0/4.1) tools.")


@natnet_app.command("decode")
def decode(
    capture: Path = typer.Argument(..., metavar="CAPTURE", help="A .pcapng or .pcap file with NatNet traffic."),
    out: Path | None = typer.Option(None, "--out", "-o", help="Write the frames to this CSV file (default: stdout)."),
    natnet_version: str | None = typer.Option(
        None, "--natnet-version", help="NatNet version X.Y, used when the capture holds no SERVERINFO."
    ),
    ports: str = typer.Option("1510,1511", "--ports", help="UDP ports of the NatNet traffic, comma-separated."),
) -> None:
    """Decode every NatNet frame of CAPTURE (UDP to or from the NatNet ports) into one row per frame.

    Columns: capture time, frame number, the timestamp suffix (SMPTE timecode, timestamp in s, camera
    mid-exposure / data-received / transmit QPC ticks, the 4.1 precision timestamp), software and system
    latency, then per rigid body rb<id>_x..qw, error, valid and per labeled marker m<model>_<marker>_x, y, z,
    size, occluded, params. The NatNet version is taken from a SERVERINFO in the capture, else --natnet-version.
    Prints a summary line (frames, dropped, parse errors, version, rate).
    """
    from beambench.common.text import printable
    from beambench.devices.natnet import wire as nw
    from beambench.devices.natnet.capture import decode_capture, frames_table
    from beambench.devices.natnet.pcap import CaptureError

    if natnet_version is not None:
        try:
            v = nw.Version.parse(natnet_version)
        except ValueError:
            fail(f"--natnet-version {natnet_version!r}: expected X.Y, e.g. 3.0, 4.0 or 4.1")
        if (v.major, v.minor) not in [(s.major, s.minor) for s in nw.SUPPORTED_VERSIONS]:
            fail(f"--natnet-version {natnet_version}: supported are 3.0, 4.0 and 4.1")
    try:
        port_list = [int(p) for p in ports.split(",") if p.strip()]
        if not port_list or any(not 0 < p < 65536 for p in port_list):
            raise ValueError
    except ValueError:
        fail(f"--ports {ports!r}: expected port numbers separated by commas, e.g. 1510,1511")
    if not capture.is_file():
        fail(f"{capture}: no such file")
    if out is not None:
        from beambench.common.outputs import output_file_problem

        problem = output_file_problem(out)  # before decoding: a link, a device, a folder, no folder
        if problem:
            fail(f"--out: {problem}")
    try:
        decoded = decode_capture(capture, natnet_version, port_list)
    except CaptureError as exc:
        message = str(exc)
        fail(message if str(capture) in message else f"{capture}: {message}")
    except ValueError as exc:
        fail(f"{capture}: {exc}")
    table = frames_table(decoded)
    summary = decoded.summary(capture.name)
    if out is not None:
        try:
            table.to_csv(out, index=False)
        except OSError as exc:
            fail(f"{out}: cannot write ({exc.strerror})")
        typer.echo(summary)
        typer.echo(f"wrote {len(table)} rows to {out}")
    else:
        table.to_csv(sys.stdout, index=False)
        typer.echo(summary, err=True)
    for err in decoded.errors[:5]:
        typer.echo(f"  parse error: {printable(err)}", err=True)  # may quote what the capture holds


def register(app: typer.Typer) -> None:
    app.add_typer(natnet_app, name="natnet")
