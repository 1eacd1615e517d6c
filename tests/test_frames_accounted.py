"""Every frame a link delivers is stored, counted as unrecorded (it arrived after the run's last read), or counted
as lost or garbled (docs/safety.md, "Lost data"): bytes that are no frame on the load-cell link count as garbled;
for every stream of a run, ``received - unrecorded`` is the number of rows in the session, whether the run ended
or was stopped."""

from __future__ import annotations

import os
import random
import signal
import threading

import numpy as np
import pytest

from beambench.devices.loadcell.driver import SerialLoadCells
from beambench.devices.loadcell.protocol import encode_frame
from conftest import wait_until


def _frames(first: int, n: int) -> bytes:
    return b"".join(encode_frame(first + k, 1000 * (first + k), (k, -k, 2 * k, 7)) for k in range(n))


def _collect(lc: SerialLoadCells, want: int, timeout_s: float = 30.0) -> int:
    """Read until ``want`` frames arrived (polling, as the runner does): the rows read."""
    got = [0]

    def enough() -> bool:
        got[0] += len(lc.read())
        return got[0] >= want

    wait_until(enough, timeout_s, f"{want} frames")
    return got[0]


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("where", ["between frames", "before the first frame"])
def test_junk_bytes_on_the_load_cell_link_count_as_garbled(seed, where):
    """Bursts of random bytes written into the pty between frames (or before the first, more than a port
    opened mid-frame leaves): each burst is one garbled stretch, its bytes counted, no frame lost."""
    rng = random.Random(seed)
    master, slave = os.openpty()
    lc = SerialLoadCells(os.ttyname(slave), silence_timeout_s=None)
    bursts = [rng.randbytes(2000)] + [rng.randbytes(rng.randint(1, 300)) for _ in range(rng.randint(2, 6))]
    try:
        lc.start()
        wire = b"" if where == "between frames" else bursts[0]
        seq = 0
        for k, burst in enumerate(bursts):
            if k or where == "between frames":
                wire += _frames(seq, 20) + burst
                seq += 20
        wire += _frames(seq, 20)
        seq += 20
        for i in range(0, len(wire), 512):  # as a board writes: a little at a time
            os.write(master, wire[i : i + 512])
        assert _collect(lc, seq) == seq
        health = lc.health()
        assert health["garbled"] == len(bursts), health
        assert health["junk_bytes"] == sum(map(len, bursts)), health
        assert health["dropped"] == 0 and health["received"] == seq and health["unrecorded"] == 0
    finally:
        lc.stop()
        os.close(master)
        os.close(slave)


def test_a_corrupted_frame_counts_garbled_and_lost():
    master, slave = os.openpty()
    lc = SerialLoadCells(os.ttyname(slave), silence_timeout_s=None)
    frames = bytearray(_frames(0, 30))
    for k in (5, 17):  # a bit flipped in the counts of two frames
        frames[34 * k + 15] ^= 0x10
    try:
        lc.start()
        os.write(master, bytes(frames))
        assert _collect(lc, 28) == 28
        health = lc.health()
        assert (health["garbled"], health["dropped"], health["received"]) == (2, 2, 28), health
    finally:
        lc.stop()
        os.close(master)
        os.close(slave)


# --- a whole run on the emulated backend: every row of every stream accounted for ---------------------------
PROTOCOL = "name: emu\nsweep: {frequencies: [8, 16]}\nsettle_s: 0.6\nrecord_s: 0.6\nsim: {seed: 1}\n"


@pytest.fixture(scope="module", params=["ended", "stopped by SIGTERM"])
def run(request, tmp_path_factory):
    """An emulated run with garbage between load-cell frames: to its end, or stopped mid-step."""
    from beambench.acquisition.hub import Hub
    from beambench.acquisition.protocol.plan import motor_limits, plan
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.acquisition.runner import Runner
    from beambench.acquisition.stop_signals import StopSignal
    from beambench.backends.emulated import build_emulated_rig
    from beambench.session.slices import sim_slice
    from beambench.sinks.session_file.reader import read_session
    from beambench.sinks.session_file.writer import SessionWriter, append_general

    protocol = parse_protocol(PROTOCOL)
    rig = build_emulated_rig(sim_slice(protocol), inject={"loadcell_garbage": 0.02})
    rig.open()
    path = tmp_path_factory.mktemp("emu") / "emu.h5"
    general = {"protocol": PROTOCOL, "backend": "emulated", "identity": rig.identity()}
    writer = SessionWriter(path, general)
    hub = Hub([writer], critical=(writer,))
    hub.open([s.describe() for s in rig.streams])
    stop = StopSignal()
    if request.param != "ended":  # as the signal handler does, from wherever the signal lands
        timer = threading.Timer(1.2, stop.request, args=(signal.SIGTERM,))
        timer.start()
    result = Runner(rig, hub, plan(protocol), motor_limits(protocol), poll_s=0.1, stop=stop).run()
    assert result.status == ("completed" if request.param == "ended" else "interrupted"), result.message
    append_general(path, rig.after_run())
    return rig, read_session(path)


def test_every_row_received_is_stored_or_counted_unrecorded(run):
    _rig, s = run
    devices = s.general["devices"]
    for stream in ("mocap", "loadcell", "motor"):
        counts = {k: int(float(v)) for k, v in devices[stream].items() if k not in ("fault",) and v != ""}
        stored = len(s.streams[stream])
        assert counts["received"] - counts["unrecorded"] == stored, (stream, counts, stored)
        assert stored > 0


def test_garbage_between_load_cell_frames_is_counted_in_the_session(run):
    rig, s = run
    mcu = rig.peers[0].reported["loadcells"]
    garbled = int(s.general["devices"]["loadcell"]["garbled"])
    assert mcu.injected.garbage_bursts > 0
    # each burst the driver read is one garbled stretch (the emulator goes on sending for a moment after the driver
    # stopped: those bursts were never read); the pty tests above count them exactly
    assert 0 < garbled <= mcu.injected.garbage_bursts
    seq = s.streams["loadcell"].columns["seq"]
    assert (np.diff(seq) == 1).all()  # garbage costs no frame
