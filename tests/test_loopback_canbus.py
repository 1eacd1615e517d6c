"""The emulated rig's CAN bus between processes: each end hears the other and never itself, as on a real bus; it
binds loopback only, and a frame from any other socket is dropped and counted, never a motor row.
During an emulated run nothing the run's processes listen on is beyond loopback."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import can
import numpy as np
import pytest
from can.interfaces.udp_multicast.utils import pack_message

from beambench.devices.odrive import cansimple as cs
from beambench.emulators.canbus import LoopbackCanBus
from beambench.sinks.session_file.reader import read_session
from conftest import armed_for, wait_until


def drain(bus: can.BusABC, timeout: float = 0.3) -> list[can.Message]:
    out = []
    while (msg := bus.recv(timeout=timeout)) is not None:
        out.append(msg)
        timeout = 0.05
    return out


def test_each_end_hears_the_other_and_never_itself():
    host = LoopbackCanBus(0)
    peer = LoopbackCanBus(0, peer_port=host.port)
    host.connect(peer.port)
    try:
        for i in range(5):
            host.send(can.Message(arbitration_id=0x10 + i, data=[i], is_extended_id=False))
        peer.send(can.Message(arbitration_id=0x7F, data=[1, 2, 3], is_extended_id=False))
        at_peer, at_host = drain(peer), drain(host)
        assert [m.arbitration_id for m in at_peer] == [0x10, 0x11, 0x12, 0x13, 0x14]
        assert [m.arbitration_id for m in at_host] == [0x7F] and bytes(at_host[0].data) == b"\x01\x02\x03"
        assert all(abs(m.timestamp - time.time()) < 5 for m in at_peer + at_host)  # the receive time
        assert host.forged == peer.forged == 0
    finally:
        host.shutdown()
        peer.shutdown()


def test_it_binds_loopback_only():
    """As the kernel lists this process's UDP sockets: the bus's port is bound on 127.0.0.1, nowhere else."""
    import psutil

    bus = LoopbackCanBus(0)
    try:
        bound = [c.laddr.ip for c in psutil.Process().net_connections(kind="udp") if c.laddr.port == bus.port]
        assert bound == ["127.0.0.1"]
    finally:
        bus.shutdown()


def test_frames_from_another_socket_are_dropped_and_counted():
    host = LoopbackCanBus(0)
    peer = LoopbackCanBus(0, peer_port=host.port)
    host.connect(peer.port)
    intruder = LoopbackCanBus(0, peer_port=host.port)  # a well-formed python-can end, but not the peer
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        forged = cs.to_can(0, cs.EncoderEstimates(0.0, 999.0))
        for _ in range(100):
            intruder.send(forged)
        raw.sendto(pack_message(forged), ("127.0.0.1", host.port))
        raw.sendto(b"\x00garbage", ("127.0.0.1", host.port))
        peer.send(can.Message(arbitration_id=0x7F, data=[1], is_extended_id=False))
        got = drain(host)
        assert [m.arbitration_id for m in got] == [0x7F]
        assert host.forged == 102 and host.garbled == 0
    finally:
        for bus in (host, peer, intruder):
            bus.shutdown()
        raw.close()


def test_one_port_for_both_ends_is_refused():
    bus = LoopbackCanBus(0)
    try:
        with pytest.raises(ValueError, match="two ports"):
            bus.connect(bus.port)
    finally:
        bus.shutdown()


# --- an emulated run: forged frames from another process, and the run's listening sockets ---------------------
ENDLESS = """
name: endless
sweep: {start: 2, stop: 40, step: 0.19}
settle_s: 0.2
record_s: 0.3
sim: {seed: 5}
"""


def _socket_inodes(pid: int) -> set[str]:
    out = set()
    fd_dir = Path(f"/proc/{pid}/fd")
    for fd in fd_dir.iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            out.add(target[8:-1])
    return out


def _bound_inet(pids: list[int]) -> list[tuple[str, str, int]]:
    """(protocol, local address, port) of every IPv4/IPv6 TCP or UDP socket the processes hold (from /proc/net)."""
    inodes = set().union(*(_socket_inodes(p) for p in pids))
    found = []
    for proto in ("udp", "tcp", "udp6", "tcp6"):
        path = Path(f"/proc/net/{proto}")
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            cols = line.split()
            local, inode = cols[1], cols[9]
            if inode not in inodes:
                continue
            hexaddr, hexport = local.split(":")
            if len(hexaddr) == 8:
                addr = socket.inet_ntop(socket.AF_INET, bytes.fromhex(hexaddr)[::-1])
            else:
                raw = bytes.fromhex(hexaddr)
                addr = socket.inet_ntop(socket.AF_INET6, b"".join(raw[i : i + 4][::-1] for i in range(0, 16, 4)))
            found.append((proto, addr, int(hexport, 16)))
    return found


def _queued(pids: list[int]) -> int:
    """Bytes waiting in the receive queues of the processes' UDP sockets (from /proc/net)."""
    inodes = set().union(*(_socket_inodes(p) for p in pids))
    queued = 0
    for proto in ("udp", "udp6"):
        path = Path(f"/proc/net/{proto}")
        for line in path.read_text().splitlines()[1:] if path.exists() else []:
            cols = line.split()
            if cols[9] in inodes:
                queued += int(cols[4].split(":")[1], 16)  # tx_queue:rx_queue
    return queued


def _children(pid: int) -> list[int]:
    kids = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        with open(task / "children") as fh:
            kids += [int(x) for x in fh.read().split()]
    return kids


@pytest.mark.skipif(not Path("/proc/net/udp").exists(), reason="needs Linux /proc/net to list sockets")
def test_an_emulated_run_listens_on_loopback_only_and_counts_forged_can_frames(tmp_path):
    proto = tmp_path / "endless.yaml"
    proto.write_text(ENDLESS)
    path = tmp_path / "e.h5"
    src = str(Path(__file__).resolve().parents[1] / "src")
    env = dict(os.environ, PYTHONPATH=os.environ.get("PYTHONPATH") or src)
    cmd = [sys.executable, "-m", "beambench.cli", "run", str(proto), "-b", "emulated", "--out", str(tmp_path)]
    can_log = tmp_path / "e.asc"
    proc = subprocess.Popen(
        [*cmd, "--name", "e", "--rerun", "off", "--can-log", str(can_log)], stderr=subprocess.PIPE, env=env
    )
    intruder = None

    def armed() -> bool:
        assert proc.poll() is None, "the run ended before it armed the motor"
        return armed_for(can_log, 0.2)

    try:
        wait_until(armed, 120, "the run to arm the motor (its sockets bound, its motor rows coming)", 0.05)
        pids = [proc.pid, *_children(proc.pid)]
        bound = _bound_inet(pids)
        assert bound, "no sockets found: the listing is broken"
        wide = [b for b in bound if b[1] not in ("127.0.0.1", "::1")]
        assert not wide, f"bound beyond loopback: {wide}"
        # 100 Encoder_Estimates at 999 turn/s from another process's socket, to every UDP port of the run
        ports = sorted({port for p, addr, port in bound if p == "udp" and addr == "127.0.0.1"})
        intruder = subprocess.run(
            [
                sys.executable,
                "-c",
                "import sys, time\nfrom beambench.emulators.canbus import LoopbackCanBus\n"
                "from beambench.devices.odrive import cansimple as cs\n"
                "def pause(seconds, why):\n    time.sleep(seconds)\n"
                "frame = cs.to_can(0, cs.EncoderEstimates(0.0, 999.0))\n"
                "for port in map(int, sys.argv[1:]):\n"
                "    bus = LoopbackCanBus(0, peer_port=port)\n"
                "    for _ in range(100):\n"
                "        bus.send(frame)\n"
                "        pause(0.001, 'the intruder sends at 1 kHz, as a bus would')\n"
                "    bus.shutdown()\n",
                *map(str, ports),
            ],
            env=env,
            timeout=60,
        )
        # the run's own sockets (the motor's end of the bus among them) have read every forged datagram
        wait_until(lambda: _queued([proc.pid]) == 0, 30, "the run to read the forged datagrams")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert intruder is not None and intruder.returncode == 0
    assert proc.returncode == 3, err.decode()[-2000:]
    s = read_session(path)
    vel = s.streams["motor"].columns["velocity"]
    assert len(vel) > 50 and np.all(np.abs(vel) < 100), "a forged frame became a motor row"
    assert int(s.general["devices"]["motor"]["forged"]) == 100
