"""ODrive CAN benchmark: codec speed and command → telemetry latency on python-can's virtual bus.

Run: ``python benchmarks/bench_odrive.py`` (about 15 s). Medians of repeated runs; wall time on a shared
machine is noisy, so compare ratios rather than absolute numbers.

1. codec: µs per frame to decode with our struct codec vs. cantools on the firmware's DBC (if ../shared exists).
2. RTR round trip: driver sends Get_Bus_Voltage_Current by RTR → emulator thread answers → driver's Notifier.
3. command → telemetry: ``set_frequency(f)`` → first Encoder_Estimates row whose velocity moved
   (emulator: 10 ms cyclic estimates, a 1000 turn/s² ramp), i.e. what the runner sees after a step change.
"""

from __future__ import annotations

import statistics
import sys
import time
import timeit
import uuid
from pathlib import Path

from beambench.acquisition.capabilities import MotorLimits
from beambench.devices.odrive import cansimple as cs
from beambench.devices.odrive.can_motor import OdriveCanMotor
from beambench.devices.odrive.can_timing import CanMotorTiming
from beambench.emulators.odrive_can import EmulatedOdrive, OdriveEmulatorConfig

DBC = Path(__file__).resolve().parents[1] / ".." / "shared" / "fixtures" / "odrive" / "odrive-cansimple.dbc"


def bench_codec() -> None:
    frames = [
        cs.to_can(3, m)
        for m in (
            cs.Heartbeat(0, 8),
            cs.EncoderEstimates(12.5, 3.25),
            cs.Iq(0.5, 0.49),
            cs.BusVoltageCurrent(24.0, 0.3),
        )
    ]
    raw = [(f.arbitration_id, bytes(f.data)) for f in frames]
    n = 20000

    def ours() -> None:
        for arb, data in raw:
            cs.parse_frame(arb, data)

    t_ours = min(timeit.repeat(ours, number=n // len(raw), repeat=5)) / n * 1e6
    print(f"codec decode, ours:      {t_ours:6.2f} µs/frame")
    if not DBC.exists():
        print("codec decode, cantools:  skipped (../shared absent)")
        return
    import cantools

    db = cantools.database.load_file(str(DBC))

    def theirs() -> None:
        for arb, data in raw:
            db.decode_message(arb, data)

    t_ct = min(timeit.repeat(theirs, number=n // len(raw), repeat=5)) / n * 1e6
    print(f"codec decode, cantools:  {t_ct:6.2f} µs/frame   (cantools / ours = {t_ct / t_ours:.1f}×)")


def bench_bus(reps: int = 15) -> None:
    channel = f"bench-{uuid.uuid4().hex}"
    cfg = OdriveEmulatorConfig(node_id=1, calibrated=True, vel_ramp_rate=1000.0)
    with (
        EmulatedOdrive(channel=channel, config=cfg),
        OdriveCanMotor(channel, "virtual", 1, timing=CanMotorTiming(calibrate=False, poll_period_s=10.0)) as motor,
    ):
        motor.arm(MotorLimits(30.0, 10.0, 2.0))
        # RTR round trip
        rtts = []
        for _ in range(reps * 4):
            with motor.view.cond:
                motor.view.vbus = float("nan")
            t0 = time.perf_counter()
            motor.request(cs.Cmd.GET_BUS_VOLTAGE_CURRENT)
            while motor.latest()["bus_voltage"] != motor.latest()["bus_voltage"]:  # NaN until answered
                time.sleep(0.0001)
            rtts.append(time.perf_counter() - t0)
        print(
            f"RTR round trip:          median {statistics.median(rtts) * 1e3:6.2f} ms "
            f"(p90 {sorted(rtts)[int(0.9 * len(rtts))] * 1e3:.2f} ms, n={len(rtts)})"
        )
        # command → first telemetry row showing motion
        motor.start()
        lat = []
        for k in range(reps):
            target = 2.0 if k % 2 == 0 else 8.0
            motor.set_frequency(target)
            time.sleep(0.3)  # settle
            motor.read()
            base = motor.latest()["velocity"]
            t_cmd = time.monotonic_ns()
            motor.set_frequency(10.0 - target)
            seen = None
            while seen is None and time.monotonic_ns() - t_cmd < 1e9:
                b = motor.read()
                moved = abs(b.columns["velocity"] - base) > 0.05
                if moved.any():
                    seen = int(b.host_time_ns[moved.argmax()])
                time.sleep(0.0005)
            if seen is not None:
                lat.append((seen - t_cmd) / 1e6)
        print(
            f"command → telemetry:     median {statistics.median(lat):6.2f} ms "
            f"(min {min(lat):.2f}, max {max(lat):.2f}, n={len(lat)}; estimates are cyclic at 10 ms)"
        )


if __name__ == "__main__":
    print(f"python {sys.version.split()[0]}")
    bench_codec()
    bench_bus()
