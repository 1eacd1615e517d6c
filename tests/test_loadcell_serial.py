"""End to end over a real pseudo-terminal: emulated MCU at 1 kHz → pyserial → SerialLoadCells batches."""

import math
import threading

import numpy as np
import pytest

from beambench.acquisition.batch import Batch
from beambench.acquisition.capabilities import DeviceFault, Stream
from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration
from beambench.acquisition.streams import LOADCELL, loadcell_spec
from beambench.devices.loadcell.driver import SerialLoadCells, Unwrap32
from beambench.devices.loadcell.emulated_mcu import EmulatedLoadCellMCU, LinkFaults, McuClock
from conftest import holds_for, raised, wait_until

SENS = np.array([[20000.0, 1000.0], [21000.0, -800.0], [500.0, 19000.0], [-300.0, 20500.0]])
PLATE = LoadCellCalibration(tare=np.array([1200.0, -800.0, 450.0, -300.0]), sensitivity=SENS)
BIG_TX = 1 << 22  # a transmit buffer no scheduling stall on a busy test machine can overflow


def force(t: float) -> tuple[float, float]:
    return (1.0 + 0.5 * math.sin(2 * math.pi * 7 * t), 0.2 * math.cos(2 * math.pi * 3 * t))


def acquire(
    mcu: EmulatedLoadCellMCU,
    seconds: float,
    driver_first: bool = True,
    head_start_s: float = 0.05,
    max_lost_fraction: float | None = 0.05,
) -> tuple[Batch, SerialLoadCells]:
    """Run the MCU for ``seconds``, stop it, wait until the driver has every byte it sent, return all samples."""
    port = mcu.open()
    lc = SerialLoadCells(port, max_lost_fraction=max_lost_fraction)
    batches = []
    try:
        if driver_first:
            lc.start()
            mcu.start()
        else:
            mcu.start()
            wait_until(lambda: mcu.injected.frames >= head_start_s * mcu.rate_hz, what="the board's head start")
            lc.start()
        until = mcu.injected.frames + seconds * mcu.rate_hz

        def read() -> bool:  # ~10 batches per second, as the runner reads
            batches.append(lc.read())
            return mcu.injected.frames >= until

        wait_until(read, timeout_s=seconds + 10, what=f"{seconds:g} s of frames", interval_s=0.1)
        mcu.stop()
        bytes_in: list[int] = []

        def drained() -> bool:  # the board handed everything to the pty, the line is empty, the driver has it all
            empty = mcu.flushed() and mcu.unread() == 0
            bytes_in.append(lc.stats()["bytes_in"] if empty else -len(bytes_in) - 1)
            return len(bytes_in) >= 3 and len(set(bytes_in[-3:])) == 1

        wait_until(drained, timeout_s=10, what="every byte sent", interval_s=0.05)
        batches.append(lc.read())
    finally:
        lc.stop()
        mcu.close()
    return Batch.concat(batches), lc


def test_clean_link_at_1khz_loses_nothing_and_carries_the_force():
    mcu = EmulatedLoadCellMCU(force, PLATE, tx_buffer=BIG_TX, seed=3)
    b, lc = acquire(mcu, 1.5)
    assert isinstance(lc, Stream) and lc.describe() == loadcell_spec()
    assert b.stream == LOADCELL and b.columns["data"].dtype == np.int32
    sent = mcu.injected.frames
    assert sent > 500 and mcu.injected.frames_overflowed == 0
    np.testing.assert_array_equal(b.columns["seq"], np.arange(sent))  # every frame, in order, none lost
    st = lc.stats()
    assert (st["lost_frames"], st["crc_errors"], st["truncated"], st["bytes_discarded"]) == (0, 0, 0, 0)
    assert st["samples_delivered"] == sent
    np.testing.assert_array_equal(np.rint(np.diff(b.device_time) * 1e6), 1000)  # exactly 1 ms MCU ticks
    assert np.all(np.diff(b.host_time_ns) >= 0)
    t_true = np.arange(sent) / 1000.0
    expected = np.rint(PLATE.counts_from_force(np.array([force(t) for t in t_true])))
    np.testing.assert_array_equal(b.columns["data"], expected)
    edges = b.columns["sync_edges"]
    np.testing.assert_array_equal(edges, np.floor(t_true * 360.0))  # 360 Hz mocap exposure pulses


def test_injected_faults_are_counted_exactly():
    mcu = EmulatedLoadCellMCU(
        force,
        PLATE,
        faults=LinkFaults(crc_error_prob=0.02, drop_prob=0.02, max_drop=4, garbage_prob=0.03, max_garbage=60),
        tx_buffer=BIG_TX,
        seed=11,
    )
    b, lc = acquire(mcu, 2.0)
    inj, st = mcu.injected, lc.stats()
    assert inj.crc_errors > 5 and inj.frames_truncated > 5 and inj.garbage_bursts > 5 and inj.frames_overflowed == 0
    assert st["crc_errors"] == inj.crc_errors
    assert st["truncated"] == inj.frames_truncated
    assert st["lost_frames"] == inj.crc_errors + inj.frames_truncated
    assert st["bytes_discarded"] == (
        inj.garbage_bytes + 34 * inj.crc_errors + 34 * inj.frames_truncated - inj.bytes_dropped
    )
    assert len(b) == inj.frames - inj.crc_errors - inj.frames_truncated
    seq = b.columns["seq"]
    assert np.all(np.diff(seq) >= 1) and seq[-1] == inj.frames - 1
    # the samples that arrived are the right ones: device time still follows seq exactly
    np.testing.assert_allclose(b.device_time, seq * 1e-3, atol=1e-9)


def test_a_fault_in_the_last_frame_before_the_board_stops_is_still_counted():
    """Every other frame truncated (a fault is always followed by a clean frame, which is how the driver sees
    it): whichever frame the board stops on, the driver's count equals the injected one."""
    for seed in range(8):
        mcu = EmulatedLoadCellMCU(
            force, PLATE, faults=LinkFaults(drop_prob=1.0, max_drop=4), tx_buffer=BIG_TX, seed=seed
        )
        _, lc = acquire(mcu, 0.15)
        assert lc.stats()["truncated"] == mcu.injected.frames_truncated > 10, (seed, lc.stats(), mcu.injected)


def test_driver_opening_a_running_stream_counts_startup_bytes_not_errors():
    mcu = EmulatedLoadCellMCU(force, PLATE, seed=5)
    b, lc = acquire(mcu, 0.5, driver_first=False)
    st = lc.stats()
    assert len(b) > 100 and st["lost_frames"] == st["crc_errors"] == st["truncated"] == 0
    assert np.all(np.diff(b.columns["seq"]) == 1) and b.columns["seq"][-1] == mcu.injected.frames - 1


def test_mcu_clock_drift_shows_in_device_time():
    # exaggerated, so host timing noise on a busy machine cannot hide it: over the 1.5 s run the device clock gains
    # 75 ms; the envelope below tolerates 15 ms of receive delay in its least delayed samples (at 5000 ppm it was
    # 1.5 ms, and at load 20 on 2 cores a 1.5 s run read 8929 ppm)
    drift_ppm = 50_000.0
    mcu = EmulatedLoadCellMCU(force, PLATE, clock=McuClock(drift_ppm=drift_ppm), tx_buffer=BIG_TX, seed=2)
    b, _ = acquire(mcu, 1.5)
    np.testing.assert_array_equal(np.rint(np.diff(b.device_time) * 1e6), 1000)  # the MCU thinks it is exact
    host_s = (b.host_time_ns - b.host_time_ns[0]) * 1e-9
    dev_s = b.device_time - b.device_time[0]
    # receive latency is positive and spiky on a busy machine: fit the lower envelope (least delayed sample
    # of each tenth of the run), as a clock-sync fit would
    pick = [i[np.argmin(host_s[i] - dev_s[i])] for i in np.array_split(np.arange(len(b)), 10)]
    slope = np.polyfit(host_s[pick], dev_s[pick], 1)[0]  # device seconds per host second
    assert (slope - 1) * 1e6 == pytest.approx(drift_ppm, abs=10_000)
    assert len(b) == mcu.injected.frames  # frames arrive 5 % faster than 1 kHz, none lost


def test_32_bit_microsecond_clock_wraps_into_a_continuous_device_time():
    start = 2**32 - 400_000  # wraps 0.4 s into the run
    mcu = EmulatedLoadCellMCU(
        force, PLATE, clock=McuClock(clock_start_us=start, seq_start=2**32 - 300), tx_buffer=BIG_TX, seed=4
    )
    b, lc = acquire(mcu, 1.0)
    assert len(b) > 600 and lc.stats()["lost_frames"] == 0
    np.testing.assert_allclose(np.diff(b.device_time), 1e-3, atol=1e-9)
    assert b.device_time[0] == pytest.approx(start * 1e-6) and b.device_time[-1] > 2**32 * 1e-6
    np.testing.assert_array_equal(b.columns["seq"], 2**32 - 300 + np.arange(len(b)))  # unwrapped too


def test_unwrap_carries_across_batches_and_steps_back():
    u = Unwrap32()
    a = u(np.array([2**32 - 2, 2**32 - 1]))
    b = u(np.array([0, 3]))
    c = u(np.array([1]))
    assert list(a) + list(b) + list(c) == [2**32 - 2, 2**32 - 1, 2**32, 2**32 + 3, 2**32 + 1]


def test_port_that_disappears_raises_device_fault_after_handing_out_its_samples():
    mcu = EmulatedLoadCellMCU(force, PLATE)
    lc = SerialLoadCells(mcu.open())
    lc.start()
    mcu.start()
    wait_until(lambda: lc.stats()["samples_queued"] > 100, what="100 samples")
    mcu.close()  # the board is unplugged
    wait_until(lambda: lc.stats()["fault"], what="the port's failure")
    try:
        first = lc.read()
        assert len(first) > 50
        with pytest.raises(DeviceFault, match="failed"):
            lc.read()
        with pytest.raises(DeviceFault):
            lc.check()
    finally:
        lc.stop()
        lc.stop()  # idempotent


def test_missing_port_is_a_device_fault():
    with pytest.raises(DeviceFault, match="cannot open serial port"):
        SerialLoadCells("/dev/does-not-exist-beambench").start()


def test_ping_reports_version_and_rate():
    with EmulatedLoadCellMCU(force, PLATE, clock=McuClock(drift_ppm=100.0)) as mcu:
        mcu.start()
        found = SerialLoadCells(mcu.port).ping(0.3)
    assert found.ok and found.version == 1 and found.frames > 50
    assert found.rate_hz == pytest.approx(1000.0, rel=1e-9)  # measured on the MCU clock
    assert "protocol v1" in found.summary() and "1000.0 Hz" in found.summary()


def test_ping_on_a_silent_port_says_so():
    with EmulatedLoadCellMCU(force, PLATE) as mcu:  # opened but not sending
        found = SerialLoadCells(mcu.port).ping(0.15)
    assert not found.ok and "no valid frame" in found.error and "not found" in found.summary()


def test_frames_nobody_reads_overflow_the_boards_buffer_and_show_up_as_lost():
    """Like a real board: with no reader the pty fills, then the board's own transmit buffer, then frames are
    dropped whole (sequence numbers still advance), and the driver sees exactly those as lost — every dropped
    frame between two it received (one dropped after the last frame sent shows as a gap to no one: on a busy
    machine the reader can fall behind again just before the board stops)."""
    mcu = EmulatedLoadCellMCU(force, PLATE, tx_buffer=34 * 20, seed=8)
    b, lc = acquire(mcu, 1.0, driver_first=False, head_start_s=0.8, max_lost_fraction=None)  # counted, not a fault
    st = lc.stats()
    seq = b.columns["seq"]
    lo, hi = int(seq.min()), int(seq.max())
    inside = [q for q in mcu.overflowed_seqs if lo < q < hi]
    assert mcu.injected.frames_overflowed > 100 and len(inside) > 100
    assert set(range(lo, hi + 1)) - set(seq.tolist()) == set(inside)
    assert st["lost_frames"] == len(inside) and st["seq_gaps"] >= 1
    assert st["crc_errors"] == st["truncated"] == 0


def test_a_silence_found_by_check_is_not_raised_again_by_the_final_read():
    """The runner finds a fault either in read() or in check(), whichever runs first after the timeout; after
    the idle it drains every stream once more, and that drain must not fail on the fault that stopped the run
    (it did when check() found it first: a flaky 'final read failed' event in the session)."""
    mcu = EmulatedLoadCellMCU(force, PLATE, tx_buffer=BIG_TX, seed=4)
    port = mcu.open()
    lc = SerialLoadCells(port, silence_timeout_s=0.3)
    try:
        lc.start()
        mcu.start()
        wait_until(lambda: lc.stats()["samples_queued"] > 200, what="200 samples")
        mcu.stop()
        found = wait_until(
            lambda: raised(lc.check, DeviceFault), what="the silence"
        )  # the runner's check() finds it first
        assert "silent" in str(found) and f"on {port}" in str(found)  # which board: the port it is on
        drained = [lc.read(), lc.read()]  # what arrived before the silence, then nothing: no second raise
        assert len(drained[0]) > 100 and len(drained[1]) == 0
        with pytest.raises(DeviceFault, match="silent"):
            lc.check()  # the device is still reported as silent to whoever asks
    finally:
        lc.stop()
        mcu.close()


def test_a_reader_that_got_no_cpu_does_not_make_a_streaming_board_silent(monkeypatch):
    """A host that stalls (suspended, starved of CPU) leaves the reader thread asleep while the board's frames
    wait on the wire: the board is not silent, and a check that runs before the reader wakes must not blame it
    (it did: a 2 s SIGSTOP of a run ended as 'loadcell: silent for 2.02 s' instead of the host's stall, now and
    then under load). The reader is held here as a stall holds it, before its next read of the port (pyserial's
    read, which the driver's thread alone calls: the emulated board writes its pty's other end). Held for over ten
    timeouts it is hung, and the board is then judged on the host's clock."""
    import serial

    mcu = EmulatedLoadCellMCU(force, PLATE, tx_buffer=BIG_TX, seed=5)
    port = mcu.open()
    lc = SerialLoadCells(port, silence_timeout_s=0.1)
    awake = threading.Event()
    awake.set()
    read = serial.Serial.read
    monkeypatch.setattr(serial.Serial, "read", lambda ser, n=1: (awake.wait(), read(ser, n))[1])
    try:
        lc.start()
        mcu.start()
        wait_until(lambda: lc.last_receive_ns is not None, what="a first frame")
        awake.clear()  # the reader stops at its next read; the board keeps sending
        # 5 timeouts without a frame read: not silent, nobody was listening
        holds_for(lambda: raised(lc.check, DeviceFault) is None, 0.5, "no fault while the reader is held")
        hung = wait_until(lambda: raised(lc.check, DeviceFault), what="the hung reader")  # over 10 timeouts: hung
        assert "silent" in str(hung)
    finally:
        awake.set()
        lc.stop()
        mcu.close()
