"""Load-cell calibration: per-channel tare, least-squares matrix, and the `calibrate loadcells` walkthrough."""

import io
import time

import numpy as np
import pytest
import typer
from rich.console import Console
from typer.testing import CliRunner

from beambench.acquisition.forces.loadcell_calibration import (
    LoadCellCalibration,
    calibrate,
    fit_matrix,
    tare_counts,
)
from beambench.commands.calibrate import register
from beambench.devices.loadcell.calibrate import emulated_plate, parse_loads, walkthrough
from beambench.devices.loadcell.driver import SerialLoadCells
from beambench.devices.loadcell.emulated_mcu import EmulatedLoadCellMCU
from conftest import wait_until

RNG = np.random.default_rng(42)

BIG_TX = 1 << 22  # a transmit buffer no scheduling stall on a busy test machine can overflow


def test_tare_is_the_mean_over_time_of_each_channel():
    offsets = np.array([1200.0, -800.0, 450.0, -300.0])
    samples = offsets + RNG.normal(0, 25, (2000, 4)) + np.linspace(0, 10, 2000)[:, None]
    tare = tare_counts(samples)
    np.testing.assert_allclose(tare, offsets + 5.0, atol=2.0)  # each channel its own offset
    assert not np.allclose(tare, samples.mean())  # the lab script's bug: one mean across channels
    with pytest.raises(ValueError):
        tare_counts(samples[:, :3])


def plate_4dof():
    """A plate whose four cells also see the load's moment about two axes: counts = tare + A @ [Fn, Ft, Mx, My]."""
    a = np.array(
        [
            [20000.0, 800.0, 9000.0, 7000.0],
            [19000.0, -600.0, -8500.0, -7500.0],
            [900.0, 21000.0, 8000.0, -7200.0],
            [-700.0, 20500.0, -7800.0, 6900.0],
        ]
    )
    tare = np.array([1500.0, -900.0, 300.0, 50.0])
    return a, tare


def test_fit_recovers_a_known_matrix_from_noisy_loads():
    a, tare = plate_4dof()
    true_matrix = np.linalg.inv(a)[:2]  # the unique 2×4 map from counts to (Fn, Ft)
    loads, means = [], []
    for fn in (0.5, 1.0, 2.0):
        for ft in (-0.5, 0.0, 0.5):
            for px, py in ((0.0, 0.0), (0.03, 0.0), (0.0, 0.03), (-0.03, -0.02)):  # load position, m
                latent = np.array([fn, ft, fn * px * 10, fn * py * 10])
                samples = tare + a @ latent + RNG.normal(0, 30, (500, 4))  # 500 noisy samples per load
                loads.append((fn, ft))
                means.append(samples.mean(axis=0))
    tare_samples = tare + RNG.normal(0, 30, (1000, 4))
    cal, fit = calibrate(tare_samples, np.array(means), np.array(loads), source="test")
    assert fit.rank == 4
    np.testing.assert_allclose(cal.matrix, true_matrix, atol=2e-3 * np.abs(true_matrix).max())
    assert np.all(fit.rms < 2e-3)  # N
    np.testing.assert_allclose(fit.residuals, fit.fitted - np.array(loads))
    # a load never seen in the fit, at a new position, is measured right
    counts = tare + a @ np.array([1.3, -0.2, 1.3 * 0.3, 1.3 * -0.1])
    np.testing.assert_allclose(cal.force_from_counts(counts), [1.3, -0.2], atol=5e-3)


def test_loads_at_one_point_fit_without_amplifying_noise():
    sens = np.array([[20000.0, 1000.0], [21000.0, -800.0], [500.0, 19000.0], [-300.0, 20500.0]])
    tare = np.array([1200.0, -800.0, 450.0, -300.0])
    loads = np.array([[1, 0], [2, 0], [0, 0.5], [0, 1], [1.5, 0.5], [1, -0.5]], float)
    means = tare + loads @ sens.T + RNG.normal(0, 2, (6, 4))  # means of noisy samples
    fit = fit_matrix(means, loads, tare)
    assert fit.rank == 2  # only (Fn, Ft) directions are excited; the other two are noise and are dropped
    np.testing.assert_allclose(fit.matrix @ sens, np.eye(2), atol=1e-3)
    np.testing.assert_allclose(fit.sensitivity, sens, rtol=2e-3, atol=30)
    # the minimum-norm inverse of the plate (least channel noise in the force), not weights fitted to noise
    np.testing.assert_allclose(fit.matrix, np.linalg.pinv(sens), atol=1e-3 * np.abs(fit.matrix).max())


def test_fit_needs_both_axes_loaded():
    with pytest.raises(ValueError, match="both normal and tangential"):
        fit_matrix(np.ones((3, 4)), np.array([[1, 0], [2, 0], [3, 0]], float), np.zeros(4))


def test_fitted_calibration_survives_yaml(tmp_path):
    a, tare = plate_4dof()
    loads = np.array([[1, 0], [0, 1], [1, 1], [2, -1]], float)
    cal, _ = calibrate(tare + RNG.normal(0, 1, (50, 4)), tare + loads @ a[:, :2].T, loads, gain=[1, 2, 1, 0.5])
    cal.save(tmp_path / "lc.yaml")
    back = LoadCellCalibration.load(tmp_path / "lc.yaml")
    for k in ("tare", "gain", "matrix", "sensitivity"):
        np.testing.assert_allclose(getattr(back, k), getattr(cal, k))
    counts = tare + loads @ a[:, :2].T
    np.testing.assert_allclose(back.force_from_counts(counts), cal.force_from_counts(counts), rtol=1e-12)
    np.testing.assert_allclose(back.force_from_counts(counts), loads, atol=1e-3)


def test_parse_loads():
    assert parse_loads(["1,0", "0,0.5 2,-1;3,3"]) == [(1, 0), (0, 0.5), (2, -1), (3, 3)]
    with pytest.raises(ValueError, match="--loads 'x,1'"):
        parse_loads(["x,1"])


def test_walkthrough_over_a_pty_with_a_person_placing_weights():
    """The emulated MCU's force follows the prompts, as a person placing weights would."""
    rng = np.random.default_rng(5)
    sens = np.array([[20000.0, 0], [20000.0, 0], [0, 20000.0], [0, 20000.0]]) + rng.normal(0, 500, (4, 2))
    plate = LoadCellCalibration(tare=np.array([900.0, -100.0, 40.0, 2000.0]), sensitivity=sens)
    mcu = EmulatedLoadCellMCU(calibration=plate, noise_counts=30.0, tx_buffer=BIG_TX, seed=9)
    on_plate = {"load": (0.0, 0.0)}
    mcu.set_force(lambda t: on_plate["load"])
    prompts = []
    pending = iter([(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (2.0, 0.5), (0.5, -0.5)])

    def ask(text):  # the person reads the prompt, puts the next weight on, presses Enter
        prompts.append(text)
        on_plate["load"] = next(pending)
        return ""

    lc = SerialLoadCells(mcu.open())
    try:
        lc.start()
        mcu.start()
        loads = [(1.0, 0.0), (0.0, 1.0), (2.0, 0.5), (0.5, -0.5)]
        console = Console(file=io.StringIO())
        cal, fit = walkthrough(lc, loads, ask, console, settle_s=0.1, duration_s=0.2)
    finally:
        lc.stop()
        mcu.close()
    assert "Remove every load" in prompts[0] and "Fn = 2 N, Ft = 0.5 N" in prompts[3]
    np.testing.assert_allclose(cal.tare, plate.tare, atol=5)  # per channel, from the unloaded plate
    np.testing.assert_allclose(cal.matrix @ sens, np.eye(2), atol=5e-3)
    assert np.all(fit.rms < 5e-3)
    probe = np.array([[1.2, 0.3], [0.1, -0.8]])
    np.testing.assert_allclose(cal.force_from_counts(plate.counts_from_force(probe)), probe, atol=5e-3)


class LateReader:
    """The real driver, read by a host that is behind: read() hands over only the rows the driver received at
    least ``lag_s`` ago (as a loaded machine's calibration loop would get them)."""

    def __init__(self, stream: SerialLoadCells, lag_s: float) -> None:
        self.stream, self.lag_ns, self.held = stream, int(lag_s * 1e9), []

    def describe(self):  # type: ignore[no-untyped-def]
        return self.stream.describe()

    def read(self):  # type: ignore[no-untyped-def]
        from beambench.acquisition.batch import Batch

        got = self.stream.read()
        if len(got):
            self.held.append(got)
        if not self.held:
            return got
        b = Batch.concat(self.held)
        ready = b.host_time_ns <= time.monotonic_ns() - self.lag_ns

        def rows(mask):  # type: ignore[no-untyped-def]
            cols = {k: v[mask] for k, v in b.columns.items()}
            return Batch(b.stream, b.host_time_ns[mask], b.device_time[mask], cols)

        self.held = [rows(~ready)] if not np.all(ready) else []
        return rows(ready)


def test_a_host_that_reads_late_still_records_each_load_after_its_enter():
    """The person's Enter is the mark: frames the MCU sent before it but the host reads after it (0.3 s late,
    longer than the settle) are not the new load's."""
    rng = np.random.default_rng(6)
    sens = np.array([[20000.0, 0], [20000.0, 0], [0, 20000.0], [0, 20000.0]]) + rng.normal(0, 500, (4, 2))
    plate = LoadCellCalibration(tare=np.array([900.0, -100.0, 40.0, 2000.0]), sensitivity=sens)
    mcu = EmulatedLoadCellMCU(calibration=plate, noise_counts=30.0, tx_buffer=BIG_TX, seed=10)
    on_plate = {"load": (3.0, 3.0)}  # something left on the plate until the tare's prompt is answered
    mcu.set_force(lambda t: on_plate["load"])
    pending = iter([(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)])

    def ask(text):  # type: ignore[no-untyped-def]
        on_plate["load"] = next(pending)
        return ""

    lc = SerialLoadCells(mcu.open())
    try:
        lc.start()
        mcu.start()
        # half a second of the board's frames in (more than the reader's lag: the first prompt has some held)
        wait_until(lambda: lc.counters.received >= 0.5 * mcu.rate_hz, what="half a second of load-cell frames")
        late = LateReader(lc, 0.3)
        cal, _ = walkthrough(
            late, [(1.0, 0.0), (0.0, 1.0)], ask, Console(file=io.StringIO()), settle_s=0.1, duration_s=0.2
        )
    finally:
        lc.stop()
        mcu.close()
    np.testing.assert_allclose(cal.tare, plate.tare, atol=5)
    np.testing.assert_allclose(cal.matrix @ sens, np.eye(2), atol=5e-3)


def app():
    a = typer.Typer()
    register(a)
    return a


def test_cli_emulated_demo_with_answers_from_stdin(tmp_path):
    out = tmp_path / "cal" / "lc.yaml"
    args = ["calibrate", "loadcells", "--emulate", "--duration", "0.15", "--settle", "0.05", "--out", str(out)]
    args += ["--loads", "1,0 0,1", "--loads", "2,0.5"]
    r = CliRunner().invoke(app(), args, input="\n\n\n\ny\n")
    assert r.exit_code == 0, r.output
    assert "RMS residual" in r.output and f"saved {out}" in r.output
    cal = LoadCellCalibration.load(out)
    probe = np.array([[1.0, 0.0], [0.3, 0.7]])
    np.testing.assert_allclose(cal.force_from_counts(emulated_plate().counts_from_force(probe)), probe, atol=0.01)
    assert "3 loads" in cal.source


def test_cli_asks_for_loads_and_notices_a_plate_that_does_not_respond(tmp_path):
    out = tmp_path / "lc.yaml"
    with EmulatedLoadCellMCU(noise_counts=5.0) as mcu:  # nobody puts weights on this plate
        mcu.start()
        r = CliRunner().invoke(
            app(),
            ["calibrate", "loadcells", "--port", mcu.port, "--duration", "0.1", "--settle", "0", "--out", str(out)],
            input="\n1,0 2,0\nabc\n1,0\n\n0,1\n\n\n",
        )
    assert "one load at a time" in r.output and "'abc': expected FN,FT" in r.output  # typos are asked again
    assert "Known load 3" in r.output and "Apply load 2: Fn = 0 N, Ft = 1 N" in r.output
    assert r.exit_code == 2 and "within the noise" in r.stderr and not out.exists()


def test_cli_declined_save_writes_nothing(tmp_path):
    out = tmp_path / "lc.yaml"
    args = ["calibrate", "loadcells", "--emulate", "--duration", "0.1", "--settle", "0", "--out", str(out)]
    r = CliRunner().invoke(app(), [*args, "--loads", "1,0 0,1"], input="\n\n\nn\n")
    assert r.exit_code == 0 and "not saved" in r.output and not out.exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--loads", "1,0;x"], "--loads 'x'"),
        (["--port", "/dev/does-not-exist-beambench"], "cannot open serial port"),
        (["--emulate", "--port", "/dev/null"], "exclude each other"),
        (["--emulate", "--loads", "1,0", "--loads", "2,0"], "both normal and tangential"),
        (["--rig", "/nonexistent/rig.yaml"], "no --port given"),
        (["--emulate", "--duration", "0"], "--duration must be"),
    ],
)
def test_cli_bad_input_is_one_line_and_exit_2(args, message):
    r = CliRunner().invoke(
        app(), ["calibrate", "loadcells", "--duration", "0.1", "--settle", "0", *args], input="\n" * 5
    )
    assert r.exit_code == 2
    errors = [line for line in r.stderr.splitlines() if line.startswith("beambench: error:")]
    assert len(errors) == 1 and message in errors[0] and r.stderr.strip().endswith(errors[0])  # one line, last
    assert "Traceback" not in r.output and r.stdout == ""  # chatter on stderr; nothing saved, no result


def test_cli_no_answer_on_stdin_is_a_clean_abort():
    r = CliRunner().invoke(app(), ["calibrate", "loadcells", "--emulate", "--duration", "0.1"], input="")
    assert r.exit_code == 2 and "no answer on stdin" in r.stderr


def test_cli_help():
    r = CliRunner().invoke(app(), ["calibrate", "loadcells", "--help"])
    assert r.exit_code == 0 and "--emulate" in r.output and "tare" in r.output


def test_cli_takes_the_port_from_the_rig_file(tmp_path):
    with EmulatedLoadCellMCU(noise_counts=5.0) as mcu:
        mcu.start()
        rig = tmp_path / "rig.yaml"
        rig.write_text(f"loadcell: {{port: {mcu.port}, baudrate: 460800}}\nloadcell_calibration: lc.yaml\n")
        r = CliRunner().invoke(
            app(),
            ["calibrate", "loadcells", "--rig", str(rig), "--loads", "1,0 0,1", "--duration", "0.1"],
            input="\n\n\n",
        )
    assert "Tare (" in r.output and "samples" in r.output  # it read the emulated board named in the rig file
    assert r.exit_code == 2 and "within the noise" in r.stderr  # nobody put the weights on


class _PlateWithLostFrames:
    """A stream (in memory, on the host's real clock) of a 1 kHz plate whose frames sampled between ``lost_from``
    and ``lost_to`` seconds after it starts never reach the host (a stall that overflowed the MCU's buffer), and
    with ``every_s`` only one frame in each ``every_s`` seconds reaches it."""

    def __init__(self, lost_from: float, lost_to: float, every_s: float = 0.001) -> None:
        self.t0 = time.monotonic_ns()
        self.sent = 0
        self.lost = (lost_from, lost_to)
        self.every = round(every_s * 1e3)

    def read(self):
        from beambench.acquisition.batch import Batch

        due = int((time.monotonic_ns() - self.t0) * 1e-6)
        k = np.arange(self.sent, due)
        self.sent = due
        t = k * 1e-3
        k = k[((t < self.lost[0]) | (t >= self.lost[1])) & (k % self.every == 0)]
        dev = k * 1e-3
        counts = np.tile([100.0, 200.0, 300.0, 400.0], (len(k), 1)) + (k % 7)[:, None]
        return Batch("loadcell", self.t0 + np.rint(dev * 1e9).astype(np.int64), dev, {"data": counts})


def test_a_window_whose_frames_were_lost_is_recorded_again_while_the_plate_streams():
    """A busy host can lose the few frames of a short window (the MCU's buffer overflows): the load is still on,
    so the next window is recorded instead of failing the calibration; a plate whose every window is lost says so."""
    from beambench.devices.loadcell.calibrate import WINDOW_TRIES, CalibrationAborted, record

    plate = _PlateWithLostFrames(0.0, 0.25)  # the first window (0-0.1 s) and the next ones up to 0.25 s are lost
    rec = record(plate, 0.0, 0.1)  # type: ignore[arg-type]
    assert 50 <= len(rec.samples) <= 100, len(rec.samples)  # one window's worth (1 kHz), not zero
    np.testing.assert_allclose(rec.mean, [103.0, 203.0, 303.0, 403.0], atol=0.5)
    with pytest.raises(CalibrationAborted, match=f"in {WINDOW_TRIES} windows of 0.1 s while the plate streamed"):
        record(_PlateWithLostFrames(0.0, 0.0, every_s=1.0), 0.0, 0.1)  # type: ignore[arg-type]  # a frame a second
    with pytest.raises(CalibrationAborted, match="is the MCU connected and running"):  # silent: not a lost window
        record(_PlateWithLostFrames(0.0, 60.0), 0.0, 0.1)  # type: ignore[arg-type]
