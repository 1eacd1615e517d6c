"""Memory running out: under an address-space limit the command ends with one line and exit 1 — never
a traceback, never exit 130 (OpenBLAS, failing to start its threads, raises SIGINT at its own process); a peer of
the emulated rig that fails (a thread it cannot start) is one line too; and memory exhausted while the motor is
armed and turning still idles it: the emulated ODrive decodes the idle from the CAN bus (IDLE, no watchdog error)."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from beambench.acquisition.capabilities import DeviceFault
from beambench.acquisition.protocol.schema import parse_protocol
from beambench.backends.emulated import build_emulated_rig
from beambench.devices.odrive.cansimple import AxisState
from beambench.session.slices import sim_slice

ROOT = Path(__file__).resolve().parents[1]
BEAMBENCH = Path(sys.executable).with_name("beambench")  # the entry point a user runs (no runpy around it)
PROTOCOL = "name: mem\nsweep: {frequencies: [6]}\nsettle_s: 0.5\nrecord_s: 1.0\nsim: {seed: 2}\n"

# An emulated run whose process runs out of memory once the motor is armed and turning: a consumer thread lowers
# the address-space limit to what the process maps now (plus 16 MiB) and fills it, holding the memory until the
# run has commanded the idle (and a little longer), then prints what happened as JSON.
ARMED_SCRIPT = r"""
import json, os, resource, sys, threading, time
from pathlib import Path
from beambench.acquisition.hub import Hub
from beambench.acquisition.protocol.plan import motor_limits, plan
from beambench.acquisition.protocol.schema import parse_protocol
from beambench.acquisition.runner import Runner
from beambench.backends.emulated import build_emulated_rig
from beambench.devices.odrive.cansimple import AxisState
from beambench.session.slices import sim_slice
from beambench.common.unfinished import left_unfinished
from beambench.sinks.session_file.writer import SessionWriter

PROTOCOL = "name: oom\nsweep: {frequencies: [6]}\nsettle_s: 0.5\nrecord_s: 6.0\nsim: {seed: 2}\nmonitors: {mocap_lost_s: null}\n"
protocol = parse_protocol(PROTOCOL)
rig = build_emulated_rig(sim_slice(protocol))
rig.open()
writer = SessionWriter(Path(sys.argv[1]), {"protocol": PROTOCOL, "backend": "emulated"})
hub = Hub([writer], critical=(writer,))
hub.open([s.describe() for s in rig.streams])
seen = {"exhausted": False, "idle_while_exhausted": False, "held_mb": 0.0}
_, hard = resource.getrlimit(resource.RLIMIT_AS)


def vm_bytes():
    for line in open("/proc/self/status"):
        if line.startswith("VmSize:"):
            return int(line.split()[1]) * 1024


def wait_until(condition, timeout_s, interval_s=0.01):
    # poll until condition() holds or timeout_s passed: whether it held (a polling helper: this script cannot
    # import the tests' conftest)
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(interval_s)
    return True


motor = rig.motor
base = {"rows": 0, "tx": 0}


def armed():
    return motor.heartbeat is not None and motor.heartbeat.axis_state == AxisState.CLOSED_LOOP_CONTROL


def turning():  # armed and turning: 0.3 s of telemetry
    return motor.rows_received >= base["rows"] + 30


def idle_sent():
    return motor.idle_sent_ns is not None


def idle_frames_out():  # the idle frames went out under the limit
    return motor.tx_count >= base["tx"] + 2


def consume():
    if not wait_until(armed, 120):
        return
    base["rows"] = motor.rows_received
    if not wait_until(turning, 60):
        return
    held = []
    resource.setrlimit(resource.RLIMIT_AS, (vm_bytes() + (16 << 20), hard))
    for size in (1 << 20, 1 << 16, 1 << 12, 1 << 8, 1 << 6):
        try:
            while True:
                held.append(bytearray(size))
        except MemoryError:
            pass
    seen["exhausted"] = True
    seen["idle_while_exhausted"] = wait_until(idle_sent, 20, 0.005)
    base["tx"] = motor.tx_count
    wait_until(idle_frames_out, 20, 0.005)
    seen["held_mb"] = sum(len(b) for b in held) / 2**20
    held.clear()
    resource.setrlimit(resource.RLIMIT_AS, (hard, hard))


t = threading.Thread(target=consume, daemon=True)
t.start()
try:
    result = Runner(rig, hub, plan(protocol), motor_limits(protocol), poll_s=0.1).run()
    status, message = result.status, result.message
except MemoryError:  # the shutdown after the idle ran out too (its saving, not the idle, needs memory)
    status, message = "escaped", "MemoryError after the idle"
    rig.close()
t.join(30)
odrive = rig.peers[0].odrive.snapshot()
print(json.dumps({"status": status, "message": message, **seen, "send_errors": list(rig.motor.send_errors),
                  "odrive_state": odrive["state"], "odrive_axis_error": odrive["axis_error"]}), flush=True)
if left_unfinished() or seen["exhausted"]:  # end as the command line does under a memory limit (lifted above only so
    sys.stderr.flush()  # this could print): a library that failed to allocate may abort in its exit handler (heap damage)
    os._exit(0)
"""


# NatNet frames decoded many at a time while memory runs out, then comes back a few bytes at a time: every call
# either decodes or raises MemoryError (numpy's buffered ufuncs allocate with the GIL released, and a failure there
# is a crash, not an exception); prints how many calls did which.
BLOCK_SCRIPT = r"""
import resource
from beambench.devices.natnet import block as nb
from beambench.devices.natnet import frame as nf
from beambench.devices.natnet import protocol as nn
from beambench.devices.natnet import wire as nw

def frame(k):
    lms = tuple(nf.LabeledMarker((1 << 16) | (i + 1), (0.1 * k, 0.2, i), 0.014, 2, 1e-5) for i in range(4))
    body = nf.RigidBody(7, (0.0, 0.1 * k, 0.3), (0.0, 0.0, 0.0, 1.0), 1e-4, 1)
    sets = (nf.MarkerSetData("beam", ((0.0, 0.0, k), (1.0, 0.0, k))),)
    return nf.FrameOfData(1000 + k, marker_sets=sets, rigid_bodies=(body,), labeled_markers=lms, timestamp=k / 360)

packets = [nn.encode(frame(k), nw.V4_1) for k in range(36)]
layout = nb.frame_layout(packets[0], nw.V4_1)
assert nb.decode_block(packets, layout)[1].all()
vm = next(int(ln.split()[1]) * 1024 for ln in open("/proc/self/status") if ln.startswith("VmSize:"))
_, hard = resource.getrlimit(resource.RLIMIT_AS)
resource.setrlimit(resource.RLIMIT_AS, (vm + (8 << 20), hard))
decoded = exhausted = 0
for _ in range(6):  # the heap ends up differently each time: more chances to run out at each allocation
    held = []
    for size in (1 << 20, 1 << 16, 1 << 12, 1 << 8, 1 << 6):
        try:
            while True:
                held.append(bytearray(size))
        except MemoryError:
            pass
    while held:
        held.pop()
        try:
            decoded += int(nb.decode_block(packets, layout)[1].all())
        except MemoryError:
            exhausted += 1
resource.setrlimit(resource.RLIMIT_AS, (hard, hard))
print(decoded, exhausted)
"""


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.environ.get("PYTHONPATH") or str(ROOT / "src"), PYTHONUNBUFFERED="1")


@pytest.mark.slow
def test_memory_exhausted_while_armed_idles_the_motor(tmp_path):
    script = tmp_path / "oom_armed.py"
    script.write_text(ARMED_SCRIPT)
    # faulthandler: a C library that crashes under the limit instead of raising MemoryError (seen: a NULL thread
    # state in CPython's _PyErr_GetTopmostException, error raised with the GIL released; numpy's "error return
    # without exception set") prints where, so a failure here names the library
    env = dict(_env(), PYTHONFAULTHANDLER="1")
    proc = subprocess.run(
        [sys.executable, str(script), str(tmp_path / "oom.h5")], capture_output=True, text=True, env=env, timeout=300
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["exhausted"] and got["held_mb"] > 1, got  # the memory was taken while the motor turned
    assert got["status"] != "completed" and "memory" in got["message"].lower(), got
    assert got["idle_while_exhausted"], got  # the run commanded the idle while nothing was left
    assert not [e for e in got["send_errors"] if e.startswith("idle")], got
    assert got["odrive_state"] == AxisState.IDLE and got["odrive_axis_error"] == 0, got  # decoded, not the watchdog
    if got["status"] != "escaped":  # else the shutdown's later steps ran out too (said in the report; not the idle)
        assert "Traceback" not in proc.stderr, proc.stderr[-3000:]


def test_frames_decoded_while_memory_runs_out_raise_memory_error_never_crash(tmp_path):
    """The mocap stream decodes a poll's frames at once (devices.natnet.block) in the run's process: out of memory,
    that must be a MemoryError the run reports (and idles the motor on), not a crash of the whole process."""
    script = tmp_path / "oom_block.py"
    script.write_text(BLOCK_SCRIPT)
    proc = subprocess.run(
        [sys.executable, "-X", "faulthandler", str(script)], capture_output=True, text=True, env=_env(), timeout=120
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    decoded, exhausted = map(int, proc.stdout.split())
    assert exhausted > 0 and decoded > 0, proc.stdout  # memory ran out in the decode, and it decoded again after


def _limited(mib: int):
    def apply() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (mib << 20, resource.getrlimit(resource.RLIMIT_AS)[1]))

    return apply


@pytest.mark.parametrize("mib", [140, 150, 160, 165, 175])
def test_a_memory_limit_is_one_line_and_exit_1_never_ctrl_c(tmp_path, mib):
    """At these limits the command dies in a different import each (OpenBLAS's buffers, its threads, MuJoCo …)."""
    proto = tmp_path / "p.yaml"
    proto.write_text(PROTOCOL)
    cmd = [str(BEAMBENCH), "run", str(proto), "--backend", "emulated", "--out", str(tmp_path)]
    proc = subprocess.run(
        [*cmd, "--rerun", "off"], capture_output=True, text=True, env=_env(), timeout=300, preexec_fn=_limited(mib)
    )
    if proc.returncode == 0:  # enough memory here (another machine's libraries): nothing to check
        return
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1, (proc.returncode, proc.stderr[-2000:])  # 130 would read as Ctrl-C
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    ours = [ln for ln in lines if ln.startswith("beambench:")]
    # OpenBLAS's own lines come first where it says why; then one line of ours, or OpenBLAS's own last word
    assert (len(ours) == 1 and "out of memory" in ours[0] and lines[-1] == ours[0]) or (
        not ours and lines[-1].startswith("OpenBLAS error:")
    ), proc.stderr[-2000:]


def test_a_peer_that_fails_is_one_line_not_a_traceback(capfd):
    """A peer that fails when the run starts it (here an injection that is not a number; under a memory limit, a
    thread that cannot start) ends the rig's start with one fault naming it; the peers' process prints nothing."""
    rig = build_emulated_rig(sim_slice(parse_protocol(PROTOCOL)), inject={"loadcell_stop_s": "soon"})
    try:
        with pytest.raises(DeviceFault, match=r"emulated peers: ValueError: could not convert string to float"):
            rig.open()
    finally:
        rig.close()
    err = capfd.readouterr().err
    assert "Traceback" not in err, err


@pytest.mark.parametrize(
    "exc",
    [
        MemoryError(),
        ImportError("std::bad_alloc"),  # MuJoCo's import under a limit (pybind11 passes the C++ error on)
        RuntimeError("Could not allocate memory"),
        ImportError("/x/_mujoco.so: failed to map segment from shared object"),
        RuntimeError("can't start new thread"),
    ],
)
def test_every_shape_of_running_out_is_named_out_of_memory(exc):
    from beambench.common.out_of_memory import out_of_memory

    assert out_of_memory(exc) is not None
    wrapped = RuntimeError("the rig could not be built")
    wrapped.__cause__ = exc
    assert out_of_memory(wrapped) is not None  # also where it is the cause of another error


@pytest.mark.parametrize("exc", [ImportError("No module named 'mujoco'"), ValueError("bad alloc size")])
def test_other_errors_are_not_out_of_memory(exc):
    from beambench.common.out_of_memory import out_of_memory

    assert out_of_memory(exc) is None
