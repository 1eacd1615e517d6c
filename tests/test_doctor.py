"""``beambench doctor`` on this machine, with and without each part: a system tree of the test's own (``--root``:
``/sys/class/net``, the clock source, ``/dev``), programs on a PATH of its own (``ip`` reporting the bitrate,
``rerun``), a NatNet server emulated on loopback and the load-cell port a real pty. A missing part is one row
saying what to do; a required one (the rig file's devices, the disk) makes the exit status 1."""

from __future__ import annotations

import os
import socket
import stat
from importlib.metadata import version
from pathlib import Path

import pytest
from typer.testing import CliRunner

from beambench.acquisition.protocol.schema import load_rig_file
from beambench.cli import app
from beambench.common.vulkan import VulkanReport
from beambench.devices.loadcell.emulated_mcu import EmulatedLoadCellMCU
from beambench.devices.natnet.emulated_motive import MotiveEmulator
from beambench.session import doctor
from beambench.session.doctor import Machine, check_machine, failed, kernel_has_can, vulkan_row
from beambench.session.viewer import vulkan_available

IP_OUTPUT = """3: can0: <NOARP,UP,LOWER_UP,ECHO> mtu 16 qdisc pfifo_fast state UP mode DEFAULT group default qlen 10
    link/can  promiscuity 0 minmtu 0 maxmtu 0
    can state ERROR-ACTIVE (berr-counter tx 0 rx 0) restart-ms 0
          bitrate {bitrate} sample-point 0.875
"""


def _write(path: Path, text: str, mode: int | None = None) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    if mode is not None:
        path.chmod(mode)


def _program(folder: Path, name: str, output: str) -> None:
    _write(folder / name, f"#!/bin/sh\nprintf '%s' '{output}'\n", stat.S_IRWXU)  # a builtin: PATH may be bare


def _closed_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class World:
    """The parts of a lab machine, each present until a test takes it away."""

    def __init__(self, tmp: Path, natnet_port: int, serial_port: str) -> None:
        self.tmp, self.root, self.bin = tmp, tmp / "root", tmp / "bin"
        net = self.root / "sys" / "class" / "net"
        for name, kind in (("can0", "280"), ("eth0", "1"), ("lo", "772")):
            _write(net / name / "type", kind + "\n")
            _write(net / name / "operstate", "up\n")
        clock = self.root / "sys" / "devices" / "system" / "clocksource" / "clocksource0"
        _write(clock / "current_clocksource", "tsc\n")
        _write(clock / "available_clocksource", "tsc hpet acpi_pm\n")
        _write(self.root / "dev" / "ttyACM0", "")
        _program(self.bin, "ip", IP_OUTPUT.format(bitrate=250000))
        _program(self.bin, "rerun", f"rerun-cli {version('rerun-sdk')} [rustc 1.85]\n")
        self.rig = tmp / "rig.yaml"
        self.write_rig(natnet_port, serial_port)

    def write_rig(self, natnet_port: int, serial_port: str, bitrate: int = 250000) -> None:
        self.rig.write_text(
            f"natnet: {{server_address: 127.0.0.1, local_address: 127.0.0.1, command_port: {natnet_port}, "
            f"multicast: false}}\nodrive: {{transport: can, interface: socketcan, channel: can0, bitrate: {bitrate}}}\n"
            f"loadcell: {{port: '{serial_port}'}}\n"
        )

    def machine(self, **kw) -> Machine:
        return Machine(load_rig_file(self.rig), self.tmp, self.root, str(self.bin), **kw)


SOFTWARE_VULKAN = VulkanReport("/usr/lib/x86_64-linux-gnu/libvulkan.so.1", ["llvmpipe (CPU (software))"])
NO_VULKAN_DRIVER = VulkanReport("/usr/lib/x86_64-linux-gnu/libvulkan.so.1", [], "no Vulkan driver found")


@pytest.fixture
def world(tmp_path, monkeypatch):
    # The Vulkan driver is a part of the test's machine like /sys and PATH: the loader's answer is faked (the real
    # loader is asked by the tests at the end of this module, which hold on a machine with or without Vulkan).
    monkeypatch.setattr(doctor, "vulkan_devices", lambda: SOFTWARE_VULKAN)
    with (
        MotiveEmulator(command_port=0, multicast=False, wait_for_client=False) as motive,
        EmulatedLoadCellMCU() as mcu,
    ):
        yield World(tmp_path, motive.command_address[1], mcu.open())


def _not_ok(rows):
    return [r for r in rows if r.state != "ok"]


def test_a_machine_with_every_part_has_only_ok_rows_and_exits_0(world):
    rows = check_machine(world.machine())
    assert _not_ok(rows) == [], _not_ok(rows)
    parts = [r.part for r in rows]
    assert parts == [
        "motor bus (SocketCAN)",
        "mocap (NatNet)",
        "load cells (serial)",
        "disk for sessions",
        "Vulkan (Rerun viewer)",
        "rerun viewer",
        "clock source",
    ]
    found = {r.part: r.found for r in rows}
    assert "can0 at 250000 bit/s" in found["motor bus (SocketCAN)"]
    assert "answers at 127.0.0.1" in found["mocap (NatNet)"]
    assert found["Vulkan (Rerun viewer)"].count("via ") == 1  # the device the loader offers, and the loader
    res = CliRunner().invoke(
        app,
        ["doctor", "--rig", str(world.rig), "--root", str(world.root), "--out", str(world.tmp)],
        env={"PATH": str(world.bin)},
    )
    assert res.exit_code == 0, res.output
    assert res.stdout.count(" ok ") == 7 and "missing" not in res.stdout, res.stdout


def _take_away(world: World, part: str, monkeypatch) -> dict:
    """Remove one part; returns Machine arguments the case needs."""
    net = world.root / "sys" / "class" / "net"
    if part == "no CAN interface":
        for f in (net / "can0").iterdir():
            f.unlink()
        (net / "can0").rmdir()
    elif part == "CAN interface down":
        _write(net / "can0" / "operstate", "down\n")
    elif part == "CAN at another bitrate":
        _program(world.bin, "ip", IP_OUTPUT.format(bitrate=500000))
    elif part == "no serial port":
        world.write_rig(load_rig_file(world.rig).natnet.command_port, str(world.tmp / "ttyACM9"))
    elif part == "no NatNet server":
        world.write_rig(_closed_udp_port(), load_rig_file(world.rig).loadcell.port)
    elif part == "no disk space":
        return {"min_free_gb": 1e9}
    elif part == "no Vulkan driver":
        monkeypatch.setattr(doctor, "vulkan_devices", lambda: NO_VULKAN_DRIVER)
    elif part == "no rerun program":
        (world.bin / "rerun").unlink()
    elif part == "another rerun version":
        _program(world.bin, "rerun", "rerun-cli 0.1.2\n")
    elif part == "a slow clock source":
        clock = world.root / "sys" / "devices" / "system" / "clocksource" / "clocksource0"
        _write(clock / "current_clocksource", "hpet\n")
    return {}


CASES = [  # (what is taken away, the row, its state, words of the fix, exit status)
    # the fix depends on the kernel (probed for real): plug the adapter in, or load CAN support
    (
        "no CAN interface",
        "motor bus (SocketCAN)",
        "missing",
        "ip link set can0 up type can bitrate 250000" if kernel_has_can() else "sudo modprobe can can_raw",
        1,
    ),
    ("CAN interface down", "motor bus (SocketCAN)", "missing", "bring it up", 1),
    ("CAN at another bitrate", "motor bus (SocketCAN)", "missing", "the rig file says 250000 bit/s", 1),
    ("no serial port", "load cells (serial)", "missing", "plug in the load-cell MCU", 1),
    ("no NatNet server", "mocap (NatNet)", "missing", "start Motive with streaming on", 1),
    ("no disk space", "disk for sessions", "missing", "free disk or write sessions elsewhere", 1),
    ("no Vulkan driver", "Vulkan (Rerun viewer)", "missing", "apt-get install mesa-vulkan-drivers libvulkan1", 0),
    ("no rerun program", "rerun viewer", "missing", "pip install rerun-sdk==", 0),
    ("another rerun version", "rerun viewer", "advice", "the viewer must match the SDK", 0),
    ("a slow clock source", "clock source", "advice", "echo tsc | sudo tee", 0),
]


@pytest.mark.parametrize(("taken", "part", "state", "fix", "code"), CASES, ids=[c[0] for c in CASES])
def test_a_missing_part_is_one_row_with_its_fix(world, monkeypatch, taken, part, state, fix, code):
    kw = _take_away(world, taken, monkeypatch)
    rows = check_machine(world.machine(**kw))
    bad = _not_ok(rows)
    assert [(r.part, r.state) for r in bad] == [(part, state)], bad
    assert fix in bad[0].todo, bad[0]
    assert failed(rows) == (code == 1)
    args = ["doctor", "--rig", str(world.rig), "--root", str(world.root), "--out", str(world.tmp)]
    if "min_free_gb" in kw:
        args += ["--min-free-gb", str(kw["min_free_gb"])]
    res = CliRunner().invoke(app, args, env={"PATH": str(world.bin)})
    assert res.exit_code == code, res.output
    assert res.stdout.count(f" {state}") == 1, res.stdout


def test_sim_only_shows_the_rigs_devices_without_requiring_them(world):
    world.write_rig(_closed_udp_port(), str(world.tmp / "ttyACM9"))
    rows = check_machine(world.machine(sim_only=True))
    assert {r.part for r in _not_ok(rows)} == {"load cells (serial)", "mocap (NatNet)"}
    assert not failed(rows)


@pytest.mark.skipif(os.geteuid() == 0, reason="root opens every port: no permission to take away")
def test_a_port_without_permission_says_dialout(world, tmp_path):
    port = tmp_path / "ttyACM5"
    port.write_text("")
    port.chmod(0)
    world.write_rig(load_rig_file(world.rig).natnet.command_port, str(port))
    bad = _not_ok(check_machine(world.machine()))
    assert [r.part for r in bad] == ["load cells (serial)"] and "dialout" in bad[0].todo


def test_the_viewer_asks_the_vulkan_loader_not_fixed_paths(monkeypatch, tmp_path):
    """The screenshot viewer's check is the loader's answer: drivers named by VK_ICD_FILENAMES that do not exist
    are no driver, whatever is installed in /usr/lib or /usr/share."""
    from beambench.session.viewer import HeadlessViewer, ViewerUnavailable, vulkan_available

    for var in ("VK_ICD_FILENAMES", "VK_DRIVER_FILES"):
        monkeypatch.setenv(var, str(tmp_path / "none.json"))
    assert not vulkan_available()
    # the loader's own words: no driver behind an installed loader, or no loader at all on this machine
    said = "needs a Vulkan driver: (no Vulkan driver found|no Vulkan loader \\(libvulkan.so.1\\) on the library path)"
    with pytest.raises(ViewerUnavailable, match=said), HeadlessViewer():
        pass


def test_the_vulkan_row_is_the_real_loaders_answer_on_this_machine(monkeypatch, tmp_path):
    """Unfaked: the row says what this machine's loader says (ok with a device, or missing with the install line),
    and drivers named by VK_ICD_FILENAMES that do not exist make it missing whether or not a loader is installed."""
    for var in ("VK_ICD_FILENAMES", "VK_DRIVER_FILES"):
        monkeypatch.delenv(var, raising=False)
    row = vulkan_row()
    if vulkan_available():
        assert row.state == "ok" and "via " in row.found, row
    else:
        assert row.state == "missing" and "apt-get install mesa-vulkan-drivers libvulkan1" in row.todo, row
    for var in ("VK_ICD_FILENAMES", "VK_DRIVER_FILES"):
        monkeypatch.setenv(var, str(tmp_path / "none.json"))
    row = vulkan_row()
    assert row.state == "missing" and not row.required, row
    assert "no Vulkan" in row.found, row


def test_the_viewer_row_finds_the_rerun_program_the_sdk_wheel_ships(monkeypatch, tmp_path):
    """On this machine (root /) the doctor asks for the viewer beambench itself starts: the wheel's own ``rerun``,
    found with nothing on PATH (an environment used without activating it)."""
    from beambench.session.doctor import rerun_row
    from beambench.sinks.viewer.spawn import rerun_binary

    shipped = rerun_binary()
    if shipped is None or "rerun_cli" not in str(shipped):
        pytest.skip("this rerun-sdk install ships no rerun_cli binary")
    monkeypatch.setenv("PATH", str(tmp_path))
    from beambench.common.resources import shipped_dir

    row = rerun_row(Machine(load_rig_file(shipped_dir("calibration") / "rig.yaml"), tmp_path))
    assert row.state == "ok" and str(shipped) in row.found, row
