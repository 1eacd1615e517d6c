"""OdriveUsbMotor's mapping logic only (limits → config properties, frequency → input_vel, watchdog, idle).

The ``odrive`` package's libusb layer cannot run here (no device, no USB), so these tests use a plain
in-process stand-in with the firmware 0.5.x property tree; the real USB path is not exercised. Every property the
stand-in has, and every one the driver writes or calls, is checked against the firmware's own interface file
(``odrive-interface-0.5.6.yaml`` in the shared fixtures): a misspelt or invented name fails the test.
"""

from __future__ import annotations

import importlib.util
import math
import time

import numpy as np
import pytest
import yaml

from beambench.acquisition.capabilities import DeviceFault, Motor, MotorLimits
from beambench.acquisition.streams import motor_spec
from beambench.devices.odrive.cansimple import (
    AxisError,
    AxisState,
    ControlMode,
    InputMode,
)
from beambench.devices.odrive.limits import LimitError
from beambench.devices.odrive.usb_motor import OdriveUsbMotor, UsbMotorTiming, ping
from conftest import pause, raised, require_shared, wait_until

LIMITS = MotorLimits(max_frequency_hz=20.0, max_current_a=8.0, amplitude_mm=2.0)
FIRMWARE_INTERFACE = ("fixtures", "odrive", "odrive-interface-0.5.6.yaml")
STAND_IN_OWN = {"feeds", "cal_s", "cal_end", "last_feed"}  # the stand-in's bookkeeping, not firmware properties
KNOWN: set[str] = set()  # every property path (``odrv.axis0.controller.input_vel``) and call (``….clear_errors()``)
UNKNOWN: list[str] = []  # names the stand-in or the driver used that the firmware does not have


def interface_paths(doc: dict, root: str = "ODrive3", prefix: str = "odrv") -> set[str]:
    """The property paths and function calls of the firmware's interface definition, from ``root`` down."""
    interfaces, paths = doc["interfaces"], set()

    def lookup(name: str, scope: str) -> tuple[dict | None, str]:  # a type name, from the innermost scope out
        parts = scope.split(".")
        for i in range(len(parts), -1, -1):
            full = ".".join([*parts[:i], name])
            if full in interfaces:
                return interfaces[full], full
        return None, scope

    def walk(iface: dict, scope: str, at: str, depth: int) -> None:
        if depth > 8:
            return
        if "implements" in iface:
            base, base_scope = lookup(iface["implements"], scope)
            if base is not None:
                walk(base, base_scope, at, depth + 1)
        paths.update(f"{at}.{name}()" for name in iface.get("functions") or {})
        for name, spec in (iface.get("attributes") or {}).items():
            paths.add(f"{at}.{name}")
            if isinstance(spec, dict) and "attributes" in spec:  # an inline interface (``config``)
                walk(spec, scope, f"{at}.{name}", depth + 1)
                continue
            kind = spec.get("type") if isinstance(spec, dict) else spec
            if isinstance(kind, str) and not kind.startswith("readonly"):
                sub, sub_scope = lookup(kind, scope)
                if sub is not None:
                    walk(sub, sub_scope, f"{at}.{name}", depth + 1)

    walk(interfaces[root], root, prefix, 0)
    return paths


@pytest.fixture(autouse=True, scope="module")
def firmware_interface():
    KNOWN.update(interface_paths(yaml.safe_load(require_shared(*FIRMWARE_INTERFACE).read_text())))
    assert {"odrv.axis0.controller.input_vel", "odrv.axis1.watchdog_feed()", "odrv.clear_errors()"} <= KNOWN


@pytest.fixture(autouse=True)
def only_firmware_names():
    UNKNOWN.clear()
    yield
    assert UNKNOWN == [], f"not in the 0.5.6 firmware's interface: {UNKNOWN}"


def _firmware_name(path: str) -> None:
    if path not in KNOWN:
        UNKNOWN.append(path)
        raise AttributeError(f"{path}: the ODrive 0.5.6 firmware has no such property")


class Node:
    """A property-tree node that records every write as (path, value) into a shared log."""

    def __init__(self, path: str, log: list, **props) -> None:
        object.__setattr__(self, "_path", path)
        object.__setattr__(self, "_log", log)
        for k, v in props.items():
            if k not in STAND_IN_OWN:
                _firmware_name(f"{path}.{k}")
            object.__setattr__(self, k, v)

    def __setattr__(self, name, value) -> None:
        _firmware_name(f"{self._path}.{name}")
        self._log.append((f"{self._path}.{name}", value))
        object.__setattr__(self, name, value)


class StandInAxis(Node):
    """``odrv.axisN`` of firmware 0.5.x: requested_state drives current_state after a calibration delay."""

    def __init__(self, path, log, cal_s=0.05):
        super().__init__(
            path,
            log,
            error=0,
            current_state=int(AxisState.IDLE),
            feeds=0,
            cal_s=cal_s,
            cal_end=None,
            last_feed=time.monotonic(),
            config=Node(f"{path}.config", log, watchdog_timeout=0.0, enable_watchdog=False),
            controller=Node(
                f"{path}.controller",
                log,
                input_vel=0.0,
                error=0,
                config=Node(
                    f"{path}.controller.config",
                    log,
                    vel_limit=2.0,
                    control_mode=int(ControlMode.POSITION_CONTROL),
                    input_mode=int(InputMode.PASSTHROUGH),
                    vel_ramp_rate=1.0,
                ),
            ),
            motor=Node(
                f"{path}.motor",
                log,
                error=0,
                is_calibrated=False,
                config=Node(f"{path}.motor.config", log, current_lim=10.0),
                current_control=Node(f"{path}.motor.current_control", log, Iq_measured=0.25),
            ),
            encoder=Node(f"{path}.encoder", log, error=0, is_ready=False, pos_estimate=1.5, vel_estimate=0.0),
        )

    def __getattribute__(self, name):
        if name in ("current_state", "error"):
            object.__getattribute__(self, "_watchdog")()
        if name == "current_state":
            end = object.__getattribute__(self, "cal_end")
            if end is not None and time.monotonic() >= end:
                object.__setattr__(self, "cal_end", None)
                self.motor.is_calibrated = self.encoder.is_ready = True
                object.__setattr__(self, "current_state", int(AxisState.IDLE))
        return object.__getattribute__(self, name)

    def __setattr__(self, name, value):
        super().__setattr__(name, value)
        if name != "requested_state":
            return
        if value == AxisState.FULL_CALIBRATION_SEQUENCE:
            object.__setattr__(self, "current_state", int(value))
            object.__setattr__(self, "cal_end", time.monotonic() + self.cal_s)
        elif value == AxisState.CLOSED_LOOP_CONTROL:
            ok = self.motor.is_calibrated and self.encoder.is_ready and not self.error
            object.__setattr__(self, "current_state", int(value) if ok else int(AxisState.IDLE))
            if not ok:
                object.__setattr__(self, "error", self.error | AxisError.INVALID_STATE)
        elif value == AxisState.IDLE:
            object.__setattr__(self, "current_state", int(AxisState.IDLE))

    def _watchdog(self):
        """The firmware's watchdog runs on its own clock: unfed past its timeout in closed loop, the axis idles."""
        get = object.__getattribute__
        config, fed = get(self, "config"), get(self, "last_feed")
        closed = get(self, "current_state") == AxisState.CLOSED_LOOP_CONTROL
        if closed and config.enable_watchdog and time.monotonic() - fed > config.watchdog_timeout:
            object.__setattr__(self, "error", get(self, "error") | AxisError.WATCHDOG_TIMER_EXPIRED)
            object.__setattr__(self, "current_state", int(AxisState.IDLE))

    def watchdog_feed(self):
        _firmware_name(f"{self._path}.watchdog_feed()")
        self._watchdog()
        object.__setattr__(self, "feeds", self.feeds + 1)
        object.__setattr__(self, "last_feed", time.monotonic())
        self._log.append((f"{self._path}.watchdog_feed()", None))


class StandInODrive(Node):
    def __init__(self):
        log: list = []
        super().__init__(
            "odrv",
            log,
            vbus_voltage=24.0,
            serial_number=0x3762364A3137,
            fw_version_major=0,
            fw_version_minor=5,
            fw_version_revision=6,
            hw_version_major=3,
            hw_version_minor=6,
            hw_version_variant=56,
        )
        object.__setattr__(self, "axis0", StandInAxis("odrv.axis0", log))
        object.__setattr__(self, "axis1", StandInAxis("odrv.axis1", log))

    def clear_errors(self):
        _firmware_name("odrv.clear_errors()")
        self._log.append(("odrv.clear_errors()", None))
        for ax in (self.axis0, self.axis1):
            object.__setattr__(ax, "error", 0)

    def writes(self, suffix: str) -> list[int]:
        return [i for i, (p, _) in enumerate(self._log) if p.endswith(suffix)]


@pytest.fixture
def odrv():
    return StandInODrive()


@pytest.fixture
def motor(odrv):
    m = OdriveUsbMotor(odrv=odrv, timing=UsbMotorTiming(poll_period_s=0.005))
    yield m
    m.close()


def test_protocol_and_identity(motor):
    assert isinstance(motor, Motor)
    motor.open()
    ident = motor.identity()
    assert ident["serial_number"] == "3762364A3137" and ident["firmware"] == "0.5.6"
    assert ident["hardware"] == "v3.6-56V"


def test_arm_maps_limits_before_calibration_and_closed_loop(motor, odrv):
    motor.arm(LIMITS)
    ax = odrv.axis0
    assert ax.controller.config.vel_limit == pytest.approx(22.0)  # 20 Hz × 1.1, never 8000
    assert ax.motor.config.current_lim == 8.0
    assert ax.controller.config.control_mode == ControlMode.VELOCITY_CONTROL
    assert ax.controller.config.input_mode == InputMode.VEL_RAMP
    assert ax.config.enable_watchdog is True and ax.config.watchdog_timeout == 0.5
    assert ax.current_state == AxisState.CLOSED_LOOP_CONTROL
    requests = [(i, v) for i, (p, v) in enumerate(odrv._log) if p == "odrv.axis0.requested_state"]
    assert [v for _, v in requests] == [AxisState.FULL_CALIBRATION_SEQUENCE, AxisState.CLOSED_LOOP_CONTROL]
    first_request = requests[0][0]
    for prop in (
        "controller.config.vel_limit",
        "motor.config.current_lim",
        "controller.config.control_mode",
        "config.enable_watchdog",
    ):
        assert odrv.writes(prop)[0] < first_request, prop
    assert odrv.writes("clear_errors()")[0] < odrv.writes("vel_limit")[0]
    assert odrv.writes("watchdog_feed()")[0] < odrv.writes("enable_watchdog")[0]  # fed before enabling
    assert odrv.axis1.controller.config.vel_limit == 2.0  # the other axis untouched


def test_skips_calibration_when_already_calibrated(motor, odrv):
    odrv.axis0.motor.is_calibrated = odrv.axis0.encoder.is_ready = True
    motor.arm(LIMITS)
    states = [v for p, v in odrv._log if p == "odrv.axis0.requested_state"]
    assert states == [AxisState.CLOSED_LOOP_CONTROL]


def test_frequency_to_input_vel_and_refusals(motor, odrv):
    with pytest.raises(DeviceFault):
        motor.set_frequency(1.0)
    motor.arm(LIMITS)
    motor.set_frequency(12.5)
    assert odrv.axis0.controller.input_vel == 12.5
    n = len(odrv.writes("input_vel"))
    for bad in (20.5, math.nan, -25.0):
        with pytest.raises(LimitError):
            motor.set_frequency(bad)
    assert len(odrv.writes("input_vel")) == n  # refused before anything was written
    assert odrv.axis0.controller.input_vel == 12.5


def test_unsafe_limits_write_nothing(motor, odrv):
    with pytest.raises(LimitError):
        motor.arm(MotorLimits(8000.0, 8.0, 2.0))
    assert odrv.writes("vel_limit") == [] and odrv.axis0.controller.config.vel_limit == 2.0


def test_watchdog_fed_while_armed_and_telemetry(motor, odrv):
    motor.start()
    motor.arm(LIMITS)
    motor.read()
    feeds = odrv.axis0.feeds
    odrv.axis0.encoder.vel_estimate = 3.0
    wait_until(lambda: odrv.axis0.feeds > feeds + 3, what="four polls that fed the watchdog")
    batch = motor.read()
    assert set(batch.columns) == set(motor_spec().columns) and len(batch) > 3
    assert batch.columns["velocity"][-1] == 3.0 and batch.columns["bus_voltage"][-1] == 24.0
    assert np.all(batch.columns["axis_state"] == AxisState.CLOSED_LOOP_CONTROL)
    motor.check()


def test_idle_on_close_restores_watchdog_and_never_raises(odrv):
    with pytest.raises(RuntimeError), OdriveUsbMotor(odrv=odrv, timing=UsbMotorTiming(poll_period_s=0.005)) as m:
        m.arm(LIMITS)
        m.set_frequency(5.0)
        raise RuntimeError("boom")
    ax = odrv.axis0
    assert ax.current_state == AxisState.IDLE and ax.controller.input_vel == 0.0
    assert ax.config.enable_watchdog is False  # as found
    m.idle()
    m.close()


def _fault_saying(motor: OdriveUsbMotor, text: str) -> DeviceFault | None:
    """The fault ``motor.check()`` raises if it says ``text`` (a condition for wait_until), else None."""
    fault = raised(motor.check, DeviceFault)
    return fault if fault is not None and text in str(fault) else None


def test_check_reports_axis_errors_and_lost_link(motor, odrv):
    motor.arm(LIMITS)
    object.__setattr__(odrv.axis0, "error", int(AxisError.WATCHDOG_TIMER_EXPIRED))
    object.__setattr__(odrv.axis0, "current_state", int(AxisState.IDLE))
    wait_until(lambda: _fault_saying(motor, "WATCHDOG_TIMER_EXPIRED"), what="a poll that read the axis error")
    with pytest.raises(DeviceFault, match="WATCHDOG_TIMER_EXPIRED"):
        motor.check()
    odrv.clear_errors()

    class Unplugged:
        def __getattr__(self, name):
            raise OSError("USB device disconnected")

    object.__setattr__(odrv.axis0, "encoder", Unplugged())
    wait_until(lambda: _fault_saying(motor, "link lost"), what="the heartbeat timeout without a good poll")
    with pytest.raises(DeviceFault, match=r"link lost.*disconnected"):
        motor.check()


def test_ping_with_stand_in_and_without_package(odrv):
    info = ping(odrv=odrv)
    assert info["found"] and info["firmware"] == "0.5.6" and info["axis0"]["state"] == "IDLE"
    if importlib.util.find_spec("odrive") is None:  # the optional extra is absent here
        missing = ping(timeout_s=0.1)
        assert missing["found"] is False and "pip install" in missing["error"]


def test_idle_is_said_only_once_the_axis_reports_idle(odrv):
    """After idle(), "motor idle" only when the axis's current_state reads IDLE; an axis that stays in closed loop
    (a stuck request) gives "idle NOT confirmed" and names what idles it then (the watchdog)."""
    from beambench.acquisition.capabilities import ConfirmsIdle

    m = OdriveUsbMotor(odrv=odrv, timing=UsbMotorTiming(poll_period_s=0.005, idle_confirm_s=0.2))
    assert isinstance(m, ConfirmsIdle)
    m.arm(LIMITS)
    m.idle()
    said = m.confirm_idle()
    assert said.startswith("motor idle (") and "IDLE" in said, said
    m.close()

    class Stuck(StandInAxis):
        def __setattr__(self, name, value):
            if name == "requested_state" and value == AxisState.IDLE:
                Node.__setattr__(self, name, value)  # the request is written but the axis stays where it is
                return
            super().__setattr__(name, value)

    stuck = StandInODrive()
    object.__setattr__(stuck, "axis0", Stuck("odrv.axis0", stuck._log))
    m = OdriveUsbMotor(odrv=stuck, timing=UsbMotorTiming(poll_period_s=0.005, idle_confirm_s=0.2))
    m.arm(LIMITS)
    t0 = time.monotonic()
    m.idle()
    said = m.confirm_idle()
    assert "NOT confirmed" in said and "watchdog" in said and "0.5 s" in said, said
    assert time.monotonic() - t0 < 2.0
    m.close()


def test_a_stalled_host_is_named_not_blamed_on_the_usb_link(tmp_path):
    """SIGSTOP of the process that polls the axis for 1 s: check() says the host stalled, not "USB link lost"."""
    import os
    import signal
    import subprocess
    import sys
    from pathlib import Path

    script = tmp_path / "stall.py"
    script.write_text(
        "import sys\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "import yaml\n"
        "from conftest import wait_until\n"
        "from test_odrive_usb import KNOWN, LIMITS, StandInODrive, interface_paths\n"
        f"KNOWN.update(interface_paths(yaml.safe_load(open({str(require_shared(*FIRMWARE_INTERFACE))!r}).read())))\n"
        "from beambench.devices.odrive.usb_motor import OdriveUsbMotor, UsbMotorTiming\n"
        "from beambench.acquisition.capabilities import DeviceFault\n"
        "odrv = StandInODrive()\n"
        "m = OdriveUsbMotor(odrv=odrv, timing=UsbMotorTiming(poll_period_s=0.005))\n"
        "m.arm(LIMITS)\n"
        "print('armed', flush=True)\n"
        "sys.stdin.readline()\n"
        "fed = odrv.axis0.feeds\n"
        "wait_until(lambda: odrv.axis0.feeds > fed, what='a poll after the stall')  # the poller ran first\n"
        "try:\n"
        "    m.check(); print('no fault', flush=True)\n"
        "except DeviceFault as exc:\n"
        "    print('fault:', exc, flush=True)\n"
        "m.close()\n"
    )
    proc = subprocess.Popen(
        [sys.executable, str(script)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=dict(os.environ)
    )
    try:
        assert proc.stdout is not None and proc.stdin is not None
        assert proc.stdout.readline().strip() == "armed"
        os.kill(proc.pid, signal.SIGSTOP)
        pause(1.0, "the host's stall")
        os.kill(proc.pid, signal.SIGCONT)
        proc.stdin.write("\n")
        proc.stdin.flush()
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "host stalled for" in out and "link lost" not in out, out
    ms = int(out.split("host stalled for ")[1].split(" ms")[0])
    assert 800 <= ms <= 5000, out


def test_rows_a_full_buffer_evicts_are_counted_and_reported_lost(odrv):
    """The telemetry buffer keeps the newest rows; every row it evicts unread is ``dropped`` in ``health()``, which
    the run turns into a ``lost`` event (``ReportsHealth``), as for the CAN driver and the other streams."""
    from beambench.acquisition.capabilities import ReportsHealth
    from conftest import wait_until

    m = OdriveUsbMotor(odrv=odrv, timing=UsbMotorTiming(poll_period_s=0.002), max_buffered_rows=20)
    assert isinstance(m, ReportsHealth)
    try:
        m.start()
        wait_until(lambda: m.health()["received"] >= 50, what="50 telemetry rows polled")
        m.stop()
        counts = m.health()
        assert counts["unrecorded"] == 20  # the buffer's size: the newest rows wait
        batch = m.read()
        assert len(batch) == 20 and np.all(np.diff(batch.host_time_ns) > 0)
        after = m.health()
        assert after["dropped"] == after["received"] - 20 >= 30 and after["unrecorded"] == 0
        m.start()  # a buffer read in time loses nothing
        wait_until(lambda: m.health()["received"] >= after["received"] + 5, what="5 more rows")
        m.stop()
        assert len(m.read()) == m.health()["received"] - after["received"] and m.health()["dropped"] == after["dropped"]
    finally:
        m.close()
