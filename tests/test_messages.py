"""Error and progress messages read as one plain sentence: no raw ``[Errno N]``, no message repeated inside
itself, no nested "not a session file" wrapping, no stray blank line."""

from __future__ import annotations

import re

import pytest
from typer.testing import CliRunner

from beambench.acquisition.capabilities import DeviceFault
from beambench.cli import app
from beambench.devices.loadcell.driver import SerialLoadCells
from beambench.devices.odrive import can_ping

PROTOCOL = "name: m\nrig: contact\nsweep: {frequencies: [5, 26]}\nsettle_s: 0.2\nrecord_s: 0.3\n"


def test_a_can_bus_that_cannot_open_is_said_plainly():
    """On this machine the kernel may have no CAN at all (EAFNOSUPPORT) or no such interface (ENODEV): either way
    a sentence with what to do, never Python's ``[Errno 97] Address family not supported by protocol``."""
    info = can_ping.ping("bbnope0", "socketcan", listen_s=0.05)
    assert not info["found"]
    error = info["error"]
    assert "Errno" not in error and "Address family" not in error, error
    assert error.startswith(("SocketCAN not available on this machine", "no CAN interface bbnope0")), error


def test_a_missing_serial_port_is_named_once():
    port = "/dev/does-not-exist-beambench"
    with pytest.raises(DeviceFault) as caught:
        SerialLoadCells(port).start()
    text = str(caught.value)
    assert text.count(port) == 1 and "Errno" not in text, text
    assert text == f"loadcell: cannot open serial port {port}: no such device " + (
        "(is the load-cell MCU plugged in? `beambench doctor` lists the serial ports)"
    )


@pytest.mark.parametrize("command", [["analyze"], ["calibrate", "sim"]])
def test_a_file_that_is_not_a_session_is_one_unnested_line(tmp_path, command):
    junk = tmp_path / "junk.h5"
    junk.write_text("not hdf5 at all, but long enough to be more than a header of one" * 2)
    res = CliRunner().invoke(app, [*command, str(junk)])
    assert res.exit_code == 2, res.output
    assert res.stderr == f"beambench: error: {junk}: not a beambench session file (not HDF5)\n", res.stderr


def test_analyze_prints_no_blank_line_on_stderr(tmp_path):
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.session.run import run_session

    path = tmp_path / "m.h5"
    result = run_session(parse_protocol(PROTOCOL), PROTOCOL, "sim", path, rerun_mode="off", show_progress=False)
    assert result.status == "completed"
    res = CliRunner().invoke(app, ["analyze", str(path), "--out", str(tmp_path / "r"), "--figures", "none"])
    assert res.exit_code == 0, res.output
    assert not re.search(r"(^|\n)\s*\n", res.stderr), repr(res.stderr)
