"""Stopping a run never waits without bound: after the motor's idle the run's exit waits for the emulated peers'
process to report and then to end, never the 10-16 s (under load) of waiting for each in turn. The peers stop their
senders first and report, get :data:`REPORT_TIMEOUT_S` for that and :data:`EXIT_GRACE_S` to end, and are
killed after. A peers' process that hangs (stopped with SIGSTOP here) costs a rig's close no more than that."""

from __future__ import annotations

import contextlib
import os
import signal
import time

from beambench.acquisition.protocol.schema import parse_protocol
from beambench.backends.emulated import EXIT_GRACE_S, REPORT_TIMEOUT_S, build_emulated_rig
from beambench.session.slices import sim_slice
from conftest import process_alive

PROTOCOL = "name: bounded\nsweep: {frequencies: [6]}\nsettle_s: 0.5\nrecord_s: 1.0\nsim: {seed: 4}\n"
OTHER_CLOSES_S = 6.0  # the drivers' own bounded joins (NatNet 2 s, the CAN feeder and receiver 1 s each) and a kill


def test_the_wait_for_the_peers_is_bounded():
    assert REPORT_TIMEOUT_S + EXIT_GRACE_S <= 5.0


def test_a_hung_peers_process_does_not_hold_the_exit():
    rig = build_emulated_rig(sim_slice(parse_protocol(PROTOCOL)))
    peers = rig.peers[0]
    try:
        rig.open()
        os.kill(peers.pid, signal.SIGSTOP)  # the peers hang: no report, no exit
        t0 = time.monotonic()
        rig.close()
        took = time.monotonic() - t0
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(peers.pid, signal.SIGKILL)
        rig.close()
    assert took < REPORT_TIMEOUT_S + EXIT_GRACE_S + OTHER_CLOSES_S, took
    assert not process_alive(peers.pid)  # killed and reaped, not left behind
    assert peers.report is None  # a hung peer sent nothing: the run goes without its report
