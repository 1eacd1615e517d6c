"""``beambench doctor``: what this machine has for each part of the rig and the tools around it, one row each
with what to do (:func:`check_machine`).

Required (the command exits 1 when one is missing): the parts the rig file names (the SocketCAN interface at
its bitrate; each registered device stream: the load-cell serial port and the permission to open it, the NatNet
server answering, any other stream's device answering its own ping) and free disk
where sessions go; with ``sim_only`` only the disk. Advisory: the Vulkan driver of the real Rerun viewer, the
``rerun`` binary, the clock source. The system is read below ``root`` (``/sys``, ``/dev``) and programs are found
on ``path``, so a test can point both at a tree of its own.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import socket
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from beambench.acquisition.protocol.schema import RigFile
from beambench.common.oserrors import CAN_KERNEL_FIX, DIALOUT_FIX, can_link_up_fix
from beambench.common.vulkan import vulkan_devices
from beambench.devices.streams import DEVICE_STREAMS
from beambench.devices.streams.registry import DeviceStream

State = Literal["ok", "missing", "advice"]
CAN_ARPHRD = "280"  # ARPHRD_CAN: /sys/class/net/<if>/type of a CAN interface
SERIAL_GLOBS = ("ttyACM*", "ttyUSB*")
GOOD_CLOCKS = {"tsc", "kvm-clock", "hyperv_clocksource_tsc_page", "arch_sys_counter"}
VULKAN_FIX = (
    "install a Vulkan driver: on Debian/Ubuntu apt-get install mesa-vulkan-drivers libvulkan1 (software "
    "rendering, no GPU needed); Fedora: dnf install mesa-vulkan-drivers vulkan-loader"
)


@dataclass(frozen=True)
class Row:
    """One part: whether this machine has it, what it has, what to do (empty when nothing)."""

    part: str
    state: State
    found: str
    todo: str = ""
    required: bool = False


@dataclass(frozen=True)
class Machine:
    """Where the doctor looks: the system root, the program search path, the rig file, the sessions' folder."""

    rig: RigFile
    sessions: Path = Path("data")
    root: Path = Path("/")
    path: str | None = None  # PATH (default: the environment's)
    sim_only: bool = False  # only the simulator is used here: the rig's devices are shown, not required
    min_free_gb: float = 2.0


def check_machine(m: Machine) -> list[Row]:
    """Every row, in a fixed order: the motor's bus, each registered device stream (in the rig's order), disk,
    viewer, clock."""
    return [
        can_row(m),
        *(stream_row(m, s) for s in DEVICE_STREAMS.values()),
        disk_row(m),
        vulkan_row(),
        rerun_row(m),
        clock_row(m),
    ]


def failed(rows: list[Row]) -> bool:
    """Whether a required part is missing (the command's exit 1)."""
    return any(r.required and r.state == "missing" for r in rows)


def _sys(m: Machine, *parts: str) -> Path:
    return m.root.joinpath("sys", *parts)


def _read(path: Path) -> str | None:
    try:
        return path.read_text().strip()
    except OSError:
        return None


def can_interfaces(m: Machine) -> dict[str, str]:
    """SocketCAN interfaces (``/sys/class/net/*/type`` == 280) with their state (operstate)."""
    net = _sys(m, "class", "net")
    found = {}
    for entry in sorted(net.glob("*")) if net.is_dir() else []:
        if _read(entry / "type") == CAN_ARPHRD:
            found[entry.name] = _read(entry / "operstate") or "unknown"
    return found


def can_bitrate(m: Machine, channel: str) -> int | None:
    """The bitrate ``ip -details link show`` reports for a CAN interface (None: no ``ip`` or not configured)."""
    ip = shutil.which("ip", path=m.path)
    if ip is None:
        return None
    try:
        out = subprocess.run([ip, "-details", "link", "show", channel], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    hit = re.search(r"\bbitrate (\d+)", out.stdout)
    return int(hit.group(1)) if hit else None


def kernel_has_can() -> bool:
    """Whether this kernel offers SocketCAN (a raw CAN socket opens)."""
    try:
        with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW):
            return True
    except OSError as exc:
        return exc.errno != errno.EAFNOSUPPORT
    except AttributeError:  # a Python built without AF_CAN (not Linux)
        return False


def can_row(m: Machine) -> Row:
    """The rig's CAN interface: present, up, at the rig file's bitrate."""
    od = m.rig.odrive
    need = not m.sim_only and od.transport == "can"
    part = "motor bus (SocketCAN)"
    if od.transport != "can" or od.interface != "socketcan":
        what = "USB" if od.transport == "usb" else f"python-can interface {od.interface}"
        return Row(part, "ok", f"not used: the rig file's ODrive is on {what}", "beambench devices pings it")
    interfaces = can_interfaces(m)
    listing = ", ".join(f"{k} ({v})" for k, v in interfaces.items()) or "no CAN interface"
    if od.channel not in interfaces:
        if not interfaces and not kernel_has_can():
            fix = f"the kernel has no CAN support: {CAN_KERNEL_FIX}"
            return Row(part, "missing", "SocketCAN not available on this machine", fix, need)
        fix = f"plug in the CAN adapter for {od.channel}, then {can_link_up_fix(od.channel, od.bitrate)}"
        return Row(part, "missing", f"{listing}; the rig file names {od.channel}", fix, need)
    state, rate = interfaces[od.channel], can_bitrate(m, od.channel)
    found = f"{listing}; {od.channel} at " + (f"{rate} bit/s" if rate else "an unknown bitrate (no `ip` output)")
    down = f"sudo ip link set {od.channel} down; {can_link_up_fix(od.channel, od.bitrate)}"
    if state.lower() == "down":
        return Row(part, "missing", found, f"bring it up: {can_link_up_fix(od.channel, od.bitrate)}", need)
    if rate is not None and rate != od.bitrate:
        return Row(part, "missing", found, f"the rig file says {od.bitrate} bit/s: {down}", need)
    return Row(part, "ok", found, "", need)


def stream_row(m: Machine, stream: DeviceStream) -> Row:
    """A registered device stream's row: the doctor's own check for the sections it knows more about (the
    load-cell port, the NatNet server), else the stream's own ping of the device its rig-file section wires."""
    special = SECTION_ROWS.get(stream.section)
    if special is not None:
        return special(m)
    need = not m.sim_only
    wired = hasattr(m.rig, stream.section)
    answer = stream.ask(m.rig) if wired else None
    if answer is None:
        why = "its driver cannot ask it who it is" if wired else "no section in this rig file"
        return Row(stream.label, "advice", f"not checked: {why}", f"see the rig file's {stream.section}: section")
    said = ", ".join(f"{k} {v}" for k, v in answer.items() if k not in ("found", "error"))
    if answer.get("found"):
        return Row(stream.label, "ok", said or "answers", "", need)
    found = f"no answer: {answer.get('error') or said or 'nothing received'}"
    return Row(
        stream.label, "missing", found, f"switch it on or correct the rig file's {stream.section}: section", need
    )


def serial_ports(m: Machine) -> list[Path]:
    """The USB serial ports (``/dev/ttyACM*``, ``/dev/ttyUSB*``)."""
    dev = m.root / "dev"
    return sorted(p for g in SERIAL_GLOBS for p in dev.glob(g))


def serial_row(m: Machine) -> Row:
    """The rig file's load-cell port: there, and openable by this user (read and write)."""
    port = m.rig.loadcell.port
    need = not m.sim_only
    ports = ", ".join(str(p) for p in serial_ports(m)) or "no USB serial port"
    part = "load cells (serial)"
    path = Path(port)
    if not path.exists():
        return Row(
            part,
            "missing",
            f"{ports}; no {port}",
            "plug in the load-cell MCU or set loadcell.port in the rig file",
            need,
        )
    if not os.access(path, os.R_OK | os.W_OK):
        return Row(part, "missing", f"{port}: no permission to open it", DIALOUT_FIX, need)
    return Row(part, "ok", f"{port}, can be opened (read and write); USB ports: {ports}", "", need)


def natnet_row(m: Machine) -> Row:
    """The NatNet server of the rig file: does it answer (SERVERINFO)?"""
    from beambench.devices.natnet import client as natnet

    nn = m.rig.natnet
    need = not m.sim_only
    where = f"{nn.server_address}:{nn.command_port}"
    try:
        info = natnet.ping(natnet.NatNetConfig.from_mapping(nn.model_dump(exclude={"markers"})))
    except Exception as exc:  # any failure to connect is the row's answer, never the doctor's crash
        fix = (
            f"start Motive with streaming on (Edit > Settings > Streaming: Broadcast Frame Data, local interface "
            f"reachable from {nn.local_address}) or set natnet.server_address"
        )
        return Row("mocap (NatNet)", "missing", f"no answer from {where}: {exc}", fix, need)
    app = " ".join(str(info[k]) for k in ("app_name", "app_version") if info.get(k)) or "a NatNet server"
    return Row("mocap (NatNet)", "ok", f"{app} answers at {where} (NatNet {info.get('natnet_version')})", "", need)


SECTION_ROWS: dict[str, Callable[[Machine], Row]] = {"loadcell": serial_row, "natnet": natnet_row}
"""The rig-file sections the doctor checks more closely than a ping (the port's permission, Motive's settings)."""


def disk_row(m: Machine) -> Row:
    """Free disk where sessions are written (the nearest folder that exists)."""
    target = next((p for p in (m.sessions, *m.sessions.absolute().parents) if p.exists()), Path("/"))
    free_gb = shutil.disk_usage(target).free / 1e9
    found = f"{free_gb:.1f} GB free at {target.absolute()}"
    if free_gb < m.min_free_gb:
        fix = f"free disk or write sessions elsewhere (run --out DIR); at least {m.min_free_gb:g} GB wanted"
        return Row("disk for sessions", "missing", found, fix, True)
    return Row("disk for sessions", "ok", found, "", True)


def vulkan_row() -> Row:
    """The Vulkan driver the real Rerun viewer renders with (view --screenshot, the live view)."""
    vk = vulkan_devices()
    if vk.usable:
        return Row("Vulkan (Rerun viewer)", "ok", f"{', '.join(vk.devices)} via {vk.loader}")
    found = f"{vk.error}" + (f" (loader {vk.loader})" if vk.loader else "")
    return Row("Vulkan (Rerun viewer)", "missing", found, VULKAN_FIX)


def rerun_row(m: Machine) -> Row:
    """The ``rerun`` viewer program beambench starts (the one the rerun-sdk wheel ships, else the first on PATH;
    on a machine read below another root, or with ``m.path`` given, the first on PATH), and whether its version
    is the SDK's."""
    from importlib.metadata import PackageNotFoundError, version

    from beambench.sinks.viewer.spawn import rerun_binary

    if m.path is None and m.root == Path("/"):
        shipped = rerun_binary()
        binary = str(shipped) if shipped is not None else None
    else:
        binary = shutil.which("rerun", path=m.path)
    try:
        sdk = version("rerun-sdk")
    except PackageNotFoundError:
        sdk = ""
    install = f"pip install rerun-sdk=={sdk}" if sdk else "pip install rerun-sdk"
    if binary is None:
        return Row("rerun viewer", "missing", "no `rerun` on PATH", f"activate beambench's environment or {install}")
    said = ""
    with contextlib.suppress(OSError, subprocess.SubprocessError):
        said = subprocess.run([binary, "--version"], capture_output=True, text=True, timeout=20).stdout.strip()
    hit = re.search(r"\d+\.\d+\.\d+", said)
    if sdk and hit and hit.group(0) != sdk:
        fix = f"the viewer must match the SDK {sdk}: {install} (or put that one first on PATH)"
        return Row("rerun viewer", "advice", f"{binary}: {hit.group(0)}", fix)
    return Row("rerun viewer", "ok", f"{binary}" + (f": {hit.group(0)}" if hit else ""))


def clock_row(m: Machine) -> Row:
    """The kernel's clock source: timestamps come from it (a slow one, e.g. hpet, jitters them)."""
    base = _sys(m, "devices", "system", "clocksource", "clocksource0")
    current = _read(base / "current_clocksource")
    available = _read(base / "available_clocksource") or ""
    if current is None:
        return Row("clock source", "advice", "unknown (no /sys clocksource)", "check the kernel's clock source")
    found = f"{current}" + (f" (available: {available})" if available else "")
    if current in GOOD_CLOCKS:
        return Row("clock source", "ok", found)
    fix = "slow clock reads jitter timestamps: boot with clocksource=tsc if the CPU's TSC is stable"
    if "tsc" in available.split():
        fix = f"echo tsc | sudo tee {Path('/sys/devices/system/clocksource/clocksource0/current_clocksource')}"
    return Row("clock source", "advice", found, fix)
