"""Dev-only cross-check: the PyPI ``natnet`` package (an independent NatNet client) receives our emulator.

Skipped when ``natnet`` is not installed; it is not a beambench dependency. Known limitation of that package
(0.3.0): it does not read the NatNet 4.1 precision timestamp, so on 4.1 its frame ``param`` is the low 16 bits
of our precision-timestamp seconds; everything else must agree with what our emulator sent.
"""

from __future__ import annotations

import socket

import pytest

from beambench.devices.natnet import protocol as nn
from beambench.devices.natnet import wire as nw
from beambench.devices.natnet.emulated_motive import MotiveEmulator
from conftest import wait_until

natnet = pytest.importorskip("natnet", reason="the PyPI 'natnet' package (dev-only cross-check) is not installed")


def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.mark.parametrize("version", ["3.0", "4.0", "4.1"])
def test_pypi_natnet_client_decodes_our_emulator_over_multicast(version):
    emu = MotiveEmulator(
        version=version,
        command_port=0,
        data_port=free_udp_port(),
        multicast=True,
        rigid_bodies={4: [0, 1, 2]},
        occlude={20: [1]},
        keep_sent=2000,
    )
    received, descriptions = [], []
    with emu:
        client = natnet.NatNetClient(
            server_ip_address="127.0.0.1",
            local_ip_address="127.0.0.1",
            command_port=emu.command_address[1],
            data_port=emu.data_port,
            use_multicast=True,
        )
        client.on_data_frame_received_event.handlers.append(received.append)
        client.on_data_description_received_event.handlers.append(descriptions.append)
        try:
            client.connect(timeout=2.0)
            client.run_async()
            client.request_modeldef()
            # ~0.2 s at 360 Hz; a busy machine gets longer, not fewer frames
            wait_until(lambda: len(received) > 60 and descriptions, 30, "60 frames and the model description", 0.05)
        finally:
            client.shutdown()
    v = nw.Version.parse(version)
    sent = {f.frame_number: nn.decode(nn.encode(f, v), v) for f in list(emu.sent)}  # as float32 on the wire
    assert len(received) > 50
    ms = descriptions[0].marker_sets[0]
    assert ms.name == "beam" and list(ms.marker_names) == ["stage", "tip", "foot"]
    assert descriptions[0].rigid_bodies[0].id_num == 4
    checked = 0
    for theirs in received:
        ours = sent[theirs.prefix.frame_number]
        assert [(m.id_num, tuple(m.pos), m.param) for m in theirs.labeled_markers] == [
            (m.id, m.position, m.params) for m in ours.labeled_markers
        ]
        assert [(b.id_num, tuple(b.pos), tuple(b.rot), b.tracking_valid) for b in theirs.rigid_bodies] == [
            (b.id, b.position, b.orientation, b.tracking_valid) for b in ours.rigid_bodies
        ]
        assert [tuple(p) for p in theirs.marker_sets[0].marker_pos_list] == list(ours.marker_sets[0].positions)
        s = theirs.suffix
        assert (s.timestamp, s.stamp_camera_mid_exposure, s.stamp_data_received, s.stamp_transmit) == (
            ours.timestamp,
            ours.mid_exposure,
            ours.data_received,
            ours.transmit,
        )
        if version == "4.1":
            assert s.param == ours.precision_seconds & 0xFFFF  # their known 4.1 gap, see the module docstring
        else:
            assert s.param == ours.params
        checked += 1
    assert checked == len(received)
    occluded = [m for f in received if f.prefix.frame_number == 20 for m in f.labeled_markers if m.occluded]
    assert [m.marker_id for m in occluded] == [2]
