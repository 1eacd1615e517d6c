"""Load-cell frames lost (another program reading the port mid-run): the driver's check fails past
``MAX_LOST_FRACTION`` of a window's expected frames (docs/safety.md, "Lost data")."""

from __future__ import annotations

import errno
import os
import re
import threading

import pytest

from beambench.acquisition.capabilities import DeviceFault
from beambench.devices.loadcell.driver import MAX_LOST_FRACTION, SerialLoadCells
from beambench.devices.loadcell.emulated_mcu import EmulatedLoadCellMCU
from conftest import wait_until

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

        def clean_window() -> bool:
            lc.read()
            lc.check()  # a clean link: no fault
            return lc.counters.received >= 1500

        wait_until(clean_window, 60, "1500 load-cell frames (more than one loss window of a clean link)", 0.02)
        assert lc.counters.dropped == 0
        _steal(port, stop)
        fault = wait_until(lambda: _poll(lc), 60, "the check to fail once the port is stolen", 0.02)
    finally:
        stop.set()
        lc.stop()
        mcu.close()
    # the thief takes whole frames (lost: sequence gaps), wins a read pyserial was woken for ("multiple
    # access on port"), or on a loaded host takes every frame for a whole silence timeout ("silent"): either way
    # the check fails naming the port, where it used to go on without a word
    assert fault is not None and port in str(fault), fault
    assert any(w in str(fault) for w in ("frames lost", "multiple access", "silent")), fault


def _read_after_an_overflow(threshold: float | None) -> tuple[int, DeviceFault | None]:
    """A board left unread until its transmit buffer overflowed 200 frames, then read as the runner polls until
    a fault or 1500 frames: the frames counted dropped, and the fault."""
    mcu = EmulatedLoadCellMCU(tx_buffer=34 * 20, seed=8)
    lc = SerialLoadCells(mcu.open(), max_lost_fraction=threshold)
    polled: list[DeviceFault | None] = [None]

    def fault_or_frames() -> bool:
        polled.append(_poll(lc))
        return polled[-1] is not None or lc.counters.received >= 1500

    try:
        mcu.start()
        wait_until(lambda: mcu.injected.frames_overflowed >= 200, 60, "the board to overflow its buffer")
        lc.start()
        wait_until(fault_or_frames, 60, "a fault or 1500 load-cell frames", 0.02)
    finally:
        lc.stop()
        mcu.close()
    return lc.counters.dropped, polled[-1]


def test_frames_lost_past_the_threshold_are_a_fault_and_below_it_are_counted():
    """Frames the board dropped (its transmit buffer overflowed while nobody read: sequence gaps): more than
    ``MAX_LOST_FRACTION`` of a window is a fault naming how many; with the threshold off they are only counted."""
    for threshold in (MAX_LOST_FRACTION, None):
        dropped, fault = _read_after_an_overflow(threshold)
        assert dropped >= 100
        if threshold is None:
            assert fault is None, fault
        else:
            assert fault is not None and re.search(r"\d+ of \d+ frames lost \(\d+\.\d % > 5 %\)", str(fault)), fault
