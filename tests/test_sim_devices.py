"""Sim devices: exact sample counts, device clocks, reproducibility, motor limits and states, identity."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.acquisition.batch import Batch
from beambench.acquisition.capabilities import DeviceFault, MotorLimits, Rig
from beambench.acquisition.protocol.schema import ConfigError, parse_protocol
from beambench.acquisition.streams import (
    CONTACT_MARKERS,
    loadcell_spec,
    mocap_spec,
    motor_spec,
)
from beambench.backends.sim import build_sim_rig
from beambench.session.slices import sim_slice

BASE = "sweep: {frequencies: [10]}\nlimits: {max_frequency_hz: 40}\n"


def protocol(sim: str = "", extra: str = ""):
    return parse_protocol(BASE + extra + (f"sim: {{{sim}}}\n" if sim else ""))


def limits(fmax: float = 40.0, imax: float = 10.0) -> MotorLimits:
    return MotorLimits(max_frequency_hz=fmax, max_current_a=imax, amplitude_mm=2.0)


def run(rig, freq: float, seconds: float, poll: float = 0.1) -> dict[str, Batch]:
    """Arm, drive at ``freq`` for ``seconds`` polling every ``poll``; everything read, per stream."""
    got: dict[str, list[Batch]] = {s.name: [] for s in rig.streams}
    rig.motor.arm(limits())
    rig.motor.set_frequency(freq)
    waited = 0.0
    while waited < seconds - 1e-9:
        dt = min(poll, seconds - waited)
        rig.clock.wait(dt)
        waited += dt
        for s in rig.streams:
            got[s.name].append(s.read())
    return {k: Batch.concat(v) for k, v in got.items()}


@pytest.fixture(scope="module")
def two_seconds():
    rig = build_sim_rig(sim_slice(protocol("seed: 7")))
    rig.open()
    out = run(rig, 12.0, 2.0, poll=0.037)  # odd poll size on purpose
    again = {s.name: len(s.read()) for s in rig.streams}
    ident = rig.identity()
    rig.close()
    return out, again, ident, rig


def test_rig_satisfies_the_protocols(two_seconds):
    *_, rig = two_seconds
    assert isinstance(rig, Rig)
    assert [s.name for s in rig.streams] == ["motor", "mocap", "loadcell"]
    assert rig.mocap.describe() == mocap_spec(CONTACT_MARKERS)
    assert rig.loadcell.describe() == loadcell_spec() and rig.motor.describe() == motor_spec()


def test_exact_sample_counts_and_contiguous_reads(two_seconds):
    out, again, _, rig = two_seconds
    assert rig.clock.now_ns() == 2_000_000_000
    assert abs(len(out["mocap"]) - 360 * 2) <= 1
    assert abs(len(out["loadcell"]) - 1000 * 2) <= 1
    assert abs(len(out["motor"]) - 100 * 2) <= 1
    assert again == {"motor": 0, "mocap": 0, "loadcell": 0}  # read() drained everything
    assert np.all(np.diff(out["mocap"].columns["frame"]) == 1) and out["mocap"].columns["frame"][0] == 0
    assert np.all(np.diff(out["loadcell"].columns["seq"]) == 1)
    for b in out.values():
        assert np.all(np.diff(b.host_time_ns) > 0)
        for name, spec in (
            mocap_spec(CONTACT_MARKERS)
            if b.stream == "mocap"
            else loadcell_spec()
            if b.stream == "loadcell"
            else motor_spec()
        ).columns.items():
            assert b.columns[name].dtype == np.dtype(spec.dtype)
            assert b.columns[name].shape[1:] == spec.shape
    # the load-cell MCU counted every mocap exposure
    assert out["loadcell"].columns["sync_edges"][-1] == len(out["mocap"])


def test_motor_telemetry_follows_the_crank(two_seconds):
    out, *_ = two_seconds
    mot = out["motor"]
    cols = mot.columns
    assert cols["axis_state"][0] == 1  # the sample at open(), before arm()
    assert set(cols["axis_state"][1:]) == {8} and set(cols["axis_error"]) == {0}
    late = mot.device_time > 1.0  # after the velocity ramp
    assert np.all(cols["velocity_setpoint"][1:] == 12.0)
    assert np.mean(cols["velocity"][late]) == pytest.approx(12.0, abs=0.01)
    slope = np.polyfit(mot.device_time[late], cols["position"][late], 1)[0]
    assert slope == pytest.approx(12.0, rel=1e-4)  # turns per second = Hz
    assert 0.0 < np.abs(cols["iq_measured"][late]).mean() < 5.0
    assert np.all(np.abs(cols["bus_voltage"] - 24.0) < 0.5)


def test_identity_names_model_params_timestep_integrator_version(two_seconds):
    _, _, ident, _ = two_seconds
    model = ident["model"]
    assert model["model"] == "prb3" and model["params"]["name"] == "paper" and model["params"]["k"] == 0.34
    assert model["integrator"] == "implicitfast" and "timestep_policy" in model and "timestep" in model
    assert ident["mujoco_version"].startswith("4.")
    assert ident["devices"]["mocap"]["rate_hz"] == 360.0


def test_device_clocks_obey_offset_drift_latency_and_jitter():
    clk = "{offset_s: 2.5, drift_ppm: 80.0, latency_s: 0.001, jitter_s: 0.0002}"
    rig = build_sim_rig(sim_slice(protocol(f"mocap_clock: {clk}, loadcell_clock: {{offset_s: -0.3, drift_ppm: -40}}")))
    rig.open()
    out = run(rig, 5.0, 3.0)
    rig.close()
    m = out["mocap"]
    host = m.host_time_ns * 1e-9
    true = (m.device_time - 2.5) / (1 + 80e-6)  # invert the device clock
    delay = host - true
    assert delay.min() >= 0.001 - 1e-9  # one-sided: never earlier than the latency
    assert delay.mean() == pytest.approx(0.0012, abs=5e-5)
    slope = np.polyfit(true, m.device_time, 1)[0]
    assert slope == pytest.approx(1 + 80e-6, abs=1e-9)
    assert np.allclose(np.diff(m.device_time), 1 / 360)  # samples on the device's own clock
    lc = out["loadcell"]
    fit = np.polyfit(lc.host_time_ns * 1e-9, lc.device_time, 1)
    assert fit[0] == pytest.approx(1 - 40e-6, abs=2e-7) and fit[1] == pytest.approx(
        -0.3 - 0.0005 * (1 - 40e-6), abs=2e-6
    )
    # a drifting clock really produces a different number of samples per host second
    assert len(lc) == pytest.approx(1000 * 3 * (1 - 40e-6), abs=1)


def test_clocks_by_stream_name_and_the_older_per_stream_keys_are_one_setting():
    """``sim.clocks: {mocap: …}`` is the form; ``sim.mocap_clock: …`` (the form before it) gives the same slice;
    both for one stream, or a clock for a stream the sim does not have, is one line naming the field."""
    clk = "{offset_s: 2.5, drift_ppm: 80.0}"
    new = sim_slice(protocol(f"clocks: {{mocap: {clk}, motor: {{latency_s: 0.002}}}}"))
    old = sim_slice(protocol(f"mocap_clock: {clk}, motor_clock: {{latency_s: 0.002}}"))
    assert new == old and new.clocks.of("mocap").drift_ppm == 80.0 and new.clocks.of("motor").latency_s == 0.002
    assert new.clocks.of("loadcell") == sim_slice(protocol()).clocks.of("loadcell")  # not named: the default
    with pytest.raises(ConfigError, match=r"mocap_clock and clocks\.mocap both given"):
        protocol(f"mocap_clock: {clk}, clocks: {{mocap: {clk}}}")
    with pytest.raises(ConfigError) as exc:
        sim_slice(protocol(f"clocks: {{mocpa: {clk}}}"))
    assert exc.value.field == "sim.clocks.mocpa" and "mocap" in str(exc.value) and "\n" not in str(exc.value)


def test_same_seed_same_data_other_seed_other_noise():
    def record(seed: int) -> dict[str, Batch]:
        rig = build_sim_rig(sim_slice(protocol(f"seed: {seed}")))
        rig.open()
        out = run(rig, 20.0, 0.5)
        rig.close()
        return out

    a, b, c = record(1), record(1), record(2)
    for name in a:
        assert np.array_equal(a[name].host_time_ns, b[name].host_time_ns)
        for col in a[name].columns:
            assert np.array_equal(a[name].columns[col], b[name].columns[col]), (name, col)
    assert not np.array_equal(a["mocap"].columns["data"], c["mocap"].columns["data"])
    # same physics underneath: the noise is the only difference (0.1 mm marker noise)
    diff = a["mocap"].columns["data"] - c["mocap"].columns["data"]
    assert 0.5e-4 < diff.std() < 2e-4


def test_noise_off_gives_exact_tare_counts_without_contact():
    rig = build_sim_rig(sim_slice(protocol("noise: false, plate_gap_mm: 5.5")))
    rig.open()
    out = run(rig, 25.0, 1.0)
    rig.close()
    tare = np.round(rig.loadcell.cal.tare).astype(np.int32)
    assert np.all(out["loadcell"].columns["data"] == tare)


def test_motor_refuses_out_of_limit_commands_and_idles():
    rig = build_sim_rig(sim_slice(protocol()))
    rig.open()
    with pytest.raises(DeviceFault, match="before arm"):
        rig.motor.set_frequency(5.0)
    with pytest.raises(DeviceFault, match="amplitude"):
        rig.motor.arm(MotorLimits(40.0, 10.0, amplitude_mm=3.0))
    rig.motor.arm(limits(fmax=20.0))
    with pytest.raises(DeviceFault, match="refused"):
        rig.motor.set_frequency(25.0)
    rig.motor.set_frequency(20.0)
    rig.clock.wait(1.0)
    rig.motor.read()
    rig.motor.idle()
    last = rig.motor.read()  # the state change is reported at once
    assert last.columns["velocity_setpoint"][-1] == 0.0 and last.columns["axis_state"][-1] == 1
    rig.clock.wait(1.0)
    tail = rig.motor.read()
    assert np.all(tail.columns["axis_state"] == 1) and np.all(tail.columns["iq_measured"] == pytest.approx(0, abs=0.1))
    assert abs(tail.columns["velocity"][-1]) < 0.05  # the crank coasted down (ramp 50 turn/s²)
    stage = rig.mocap.read().columns["data"][:, 0, 0]
    assert np.ptp(stage[-36:]) < 2e-3  # stage at rest within the marker noise
    rig.motor.idle()  # idempotent
    rig.close()
    rig.close()


def test_current_limit_violation_faults_the_motor():
    rig = build_sim_rig(sim_slice(protocol()))
    rig.open()
    rig.motor.arm(limits(imax=0.05))
    rig.motor.set_frequency(30.0)
    with pytest.raises(DeviceFault, match="current"):
        for _ in range(20):
            rig.clock.wait(0.1)
            rig.motor.check()
    batch = rig.motor.read()
    assert batch.columns["axis_error"][-1] != 0 and batch.columns["axis_state"][-1] == 1
    with pytest.raises(DeviceFault):
        rig.motor.set_frequency(5.0)
    rig.close()


def test_prefetching_the_next_chunk_changes_nothing():
    """The worker-thread prefetch is undone by commands and odd waits: data identical to plain stepping."""

    def record(prefetch: bool) -> dict[str, Batch]:
        rig = build_sim_rig(sim_slice(protocol("seed: 5, plate_gap_mm: 1.0")), prefetch=prefetch)
        rig.open()
        rig.motor.arm(limits())
        got: dict[str, list[Batch]] = {s.name: [] for s in rig.streams}
        for f, waits in ((8.0, [0.1] * 5), (30.0, [0.1, 0.1, 0.05, 0.2, 0.2, 0.2]), (15.0, [0.3] * 3)):
            rig.motor.set_frequency(f)
            for w in waits:
                rig.clock.wait(w)
                for s in rig.streams:
                    got[s.name].append(s.read())
        rig.motor.idle()
        rig.clock.wait(0.2)
        for s in rig.streams:
            got[s.name].append(s.read())
        rig.close()
        return {k: Batch.concat(v) for k, v in got.items()}

    a, b = record(True), record(False)
    for name in a:
        assert np.array_equal(a[name].host_time_ns, b[name].host_time_ns)
        for col in a[name].columns:
            assert np.array_equal(a[name].columns[col], b[name].columns[col]), (name, col)
    assert np.abs(default_force(a["loadcell"])).max() > 0.1  # contact happened: the test is not vacuous


def default_force(batch: Batch) -> np.ndarray:
    from beambench.acquisition.forces.loadcell_calibration import default_calibration

    return default_calibration().force_from_counts(batch.columns["data"])
