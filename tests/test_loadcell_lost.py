"""Load-cell frames lost (another program reading the port mid-run): the driver's check fails past
``MAX_LOST_FRACTION`` of a window's expected frames (docs/safety.md, "Lost data")."""

from __future__ import annotations

import errno
import os
import re
import threading
import time

import pytest

from beambench.acquisition.capabilities import DeviceFault
from beambench.devices.loadcell.driver import MAX_LOST_FRACTION, SerialLoadCells
from beambench.devices.loadcell.emulated_mcu import EmulatedLoadCellMCU

BIG_TX = 1 << 22  # no scheduling stall on a loaded machine overflows it: losses are the thief's only


def _steal(port: str, stop: threading.Event) -> int:
    """A second reader on the port (root ignores TIOCEXCL, as the stealing program did): bytes it took."""
    try:
        fd = os.open(port, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
    except OSError as exc:
        if exc.errno == errno.EBUSY:
            pytest.skip("the exclusive port cannot be opened twice here: nothing can steal it")
        raise
    taken = 0

    def run() -> None:
        nonlocal taken
        while not stop.is_set():
            try:
                taken += len(os.read(fd, 4096))
            except BlockingIOError:
                stop.wait(0.001)
        os.close(fd)

    threading.Thread(target=run, daemon=True).start()
    return taken


def _poll(lc: SerialLoadCells) -> DeviceFault | None:
    """One read and check, as the runner polls: the fault it raises, else None."""
    try:
        lc.read()
        lc.check()
    except DeviceFault as exc:
        return exc
    return None


def test_a_port_stolen_by_a_second_reader_fails_the_check_naming_the_lost_frames():
    mcu = EmulatedLoadCellMCU(tx_buffer=BIG_TX, seed=9)
    port = mcu.open()
    lc = SerialLoadCells(port)
    stop = threading.Event()
    try:
        lc.start()
        mcu.start()
        deadline = time.monotonic() + 60
        while lc.counters.received < 1500:  # more than one loss window of a clean link
            assert time.monotonic() < deadline, "no load-cell frames"
            lc.read()
            lc.check()  # a clean link: no fault
            time.sleep(0.02)
        assert lc.counters.dropped == 0
        _steal(port, stop)
        fault = None
        while fault is None and time.monotonic() < deadline + 60:
            fault = _poll(lc)
            time.sleep(0.02)
    finally:
        stop.set()
        lc.stop()
        mcu.close()
    # the thief takes whole frames (lost: sequence gaps), wins a read pyserial was woken for ("multiple
    # access on port"), or on a loaded host takes every frame for a whole silence timeout ("silent"): either way
    # the check fails naming the port, where it used to go on without a word
    assert fault is not None and port in str(fault), fault
    assert any(w in str(fault) for w in ("frames lost", "multiple access", "silent")), fault


def test_frames_lost_past_the_threshold_are_a_fault_and_below_it_are_counted():
    """Frames the board dropped (its transmit buffer overflowed while nobody read: sequence gaps): more than
    ``MAX_LOST_FRACTION`` of a window is a fault naming how many; with the threshold off they are only counted."""
    for threshold in (MAX_LOST_FRACTION, None):
        mcu = EmulatedLoadCellMCU(tx_buffer=34 * 20, seed=8)
        port = mcu.open()
        lc = SerialLoadCells(port, max_lost_fraction=threshold)
        fault = None
        try:
            mcu.start()
            deadline = time.monotonic() + 60
            while mcu.injected.frames_overflowed < 200:  # nobody reads yet: the board drops whole frames
                assert time.monotonic() < deadline, "the board never overflowed"
                time.sleep(0.01)
            lc.start()
            while lc.counters.received < 1500 and fault is None:
                assert time.monotonic() < deadline, "no load-cell frames"
                fault = _poll(lc)
                time.sleep(0.02)
        finally:
            lc.stop()
            mcu.close()
        assert lc.counters.dropped >= 100
        if threshold is None:
            assert fault is None, fault
        else:
            assert fault is not None and re.search(r"\d+ of \d+ frames lost \(\d+\.\d % > 5 %\)", str(fault)), fault
