"""The emulated rig's CAN bus between processes: each end hears the other and never itself, as on a real bus."""

from __future__ import annotations

import can
import pytest

from beambench.emulators.canbus import LoopbackCanBus, new_channel


def drain(bus: can.BusABC, timeout: float = 0.3) -> list[can.Message]:
    out = []
    while (msg := bus.recv(timeout=timeout)) is not None:
        out.append(msg)
        timeout = 0.05
    return out


def test_each_end_hears_the_other_and_never_itself():
    group, host_port, peer_port = new_channel()
    assert host_port != peer_port
    host = LoopbackCanBus(group, host_port, send_port=peer_port)
    peer = LoopbackCanBus(group, peer_port, send_port=host_port)
    try:
        for i in range(5):
            host.send(can.Message(arbitration_id=0x10 + i, data=[i], is_extended_id=False))
        peer.send(can.Message(arbitration_id=0x7F, data=[1, 2, 3], is_extended_id=False))
        at_peer, at_host = drain(peer), drain(host)
        assert [m.arbitration_id for m in at_peer] == [0x10, 0x11, 0x12, 0x13, 0x14]
        assert [m.arbitration_id for m in at_host] == [0x7F] and bytes(at_host[0].data) == b"\x01\x02\x03"
        assert all(m.timestamp > 0 for m in at_peer + at_host)  # the kernel's receive time
    finally:
        host.shutdown()
        peer.shutdown()


def test_two_rigs_do_not_hear_each_other():
    a, b = new_channel(), new_channel()
    a_host = LoopbackCanBus(a[0], a[1], send_port=a[2])
    b_peer = LoopbackCanBus(b[0], b[2], send_port=b[1])
    try:
        a_host.send(can.Message(arbitration_id=0x1, data=[], is_extended_id=False))
        assert drain(b_peer, 0.2) == []
    finally:
        a_host.shutdown()
        b_peer.shutdown()


def test_one_port_for_both_ends_is_refused():
    group, port, _ = new_channel()
    with pytest.raises(ValueError, match="two ports"):
        LoopbackCanBus(group, port, send_port=port)
