"""The rig of real drivers: :class:`DeviceRig` (a motor and its streams on the wall clock, opened, checked and
closed together) and :func:`build_device_rig`, which wires the motor and every stream of the device catalogue
(:mod:`beambench.devices.streams`) from the rig file (``calibration/rig.yaml``). The emulated backend
(:mod:`beambench.backends.emulated`) builds the same :class:`DeviceRig` with its drivers pointed at wire-level peers
on this machine.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pydantic import Field, create_model

from beambench.acquisition.capabilities import (
    Connectable,
    HasSilenceTimeout,
    Identifies,
    Motor,
    ReportsEchoes,
    ReportsHealth,
    Stream,
)
from beambench.acquisition.protocol.schema import OdriveWiring, RigFile, load_rig_file
from beambench.common.resources import shipped_dir
from beambench.devices.streams import DEVICE_STREAMS, DeviceContext

DEFAULT_RIG_FILE = shipped_dir("calibration") / "rig.yaml"


class WallClock:
    """Host monotonic time; ``wait`` sleeps to deadlines so polls do not accumulate drift."""

    def __init__(self) -> None:
        self._deadline: int | None = None

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def wait(self, seconds: float) -> None:
        now = time.monotonic_ns()
        base = self._deadline if self._deadline is not None and now - self._deadline < 50_000_000 else now
        self._deadline = base + int(seconds * 1e9)
        delay = (self._deadline - time.monotonic_ns()) * 1e-9
        if delay > 0:
            time.sleep(delay)


class DeviceRig:
    """A motor and named streams of real drivers on the wall clock, plus whatever must be stopped after them
    (emulators). Opening, checking, closing, health and identity loop over the streams; each is also reachable
    by its name (``rig.mocap``), as an ophyd device's components are."""

    idle_tail_s = 0.3  # recorded after the idle command, so the session shows the motor stopping

    def __init__(
        self,
        motor: Motor,
        streams: Mapping[str, Stream],
        backend: str,
        peers: list[Any] | None = None,
        extra_identity: dict[str, Any] | None = None,
    ) -> None:
        self.clock = WallClock()
        self.motor = motor
        self.named: dict[str, Stream] = dict(streams)  # name in the rig's identity → stream
        self.streams: list[Stream] = [motor, *self.named.values()]
        self.backend = backend
        self.peers = peers or []
        self._extra = extra_identity or {}
        self._opened: list[Any] = []
        self._closed = False
        self._after_run: dict[str, Any] = {}  # what only exists after the run (NatNet ECHO table), for /general

    def open(self) -> None:
        try:
            if isinstance(self.motor, Connectable):
                self.motor.open()
            self._opened.append(self.motor)
            for s in self.streams:
                s.start()
            # emulated peers start sending once every driver listens (their servers answer from the start):
            # a real board's first second is not buffered in a port nobody has opened yet either
            for peer in self.peers:
                peer.start()
                self._opened.append(peer)
        except BaseException:
            self.close()
            raise

    def __getattr__(self, name: str) -> Stream:
        named = self.__dict__.get("named", {})
        if name in named:
            return named[name]
        raise AttributeError(f"{type(self).__name__} has no attribute or stream {name!r}")

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        with contextlib.suppress(Exception):
            self.motor.idle()
        self._keep_echoes()
        for s in self.named.values():
            with contextlib.suppress(Exception):
                s.stop()
        self._after_run["devices"] = self.device_health()
        if isinstance(self.motor, Connectable):
            with contextlib.suppress(Exception):
                self.motor.close()
        for peer in reversed(self.peers):
            with contextlib.suppress(Exception):
                peer.stop()

    def check(self) -> None:
        """Raise :class:`DeviceFault` if any device failed or went silent: the motor first, then each stream."""
        self.motor.check()
        for s in self.named.values():
            s.check()

    def silence_timeouts(self) -> dict[str, float]:
        """Each stream's silence timeout (s), for :func:`beambench.acquisition.monitors.build_monitors`."""
        out: dict[str, float] = {}
        for s in self.named.values():
            if isinstance(s, HasSilenceTimeout) and s.silence_timeout_s is not None:
                out[s.name] = float(s.silence_timeout_s)
        return out

    def device_health(self) -> dict[str, dict[str, Any]]:
        """Every driver's counters (received, dropped, garbled, forged, ...), by stream name."""
        out: dict[str, dict[str, Any]] = {}
        for s in self.streams:
            if isinstance(s, ReportsHealth):
                with contextlib.suppress(Exception):
                    out[s.name] = s.health()
        return out

    def _keep_echoes(self) -> None:
        """The mocap's ECHO table (a stream that ``ReportsEchoes``), kept before the driver stops, for the clock
        fit."""
        for s in self.named.values():
            if isinstance(s, ReportsEchoes):
                with contextlib.suppress(Exception):
                    sync = s.echo_sync()
                    if sync is not None:
                        self._after_run = {"sync": {"natnet_echo": sync}}

    def after_run(self) -> dict[str, Any]:
        """The NatNet ECHO table (for the clock fit) and every driver's counters (``devices``), known once the
        devices have stopped."""
        return dict(self._after_run)

    def identity(self) -> dict[str, Any]:
        out: dict[str, Any] = {"backend": self.backend}
        for key, dev in (("motor", self.motor), *self.named.items()):
            out[key] = dev.identity() if isinstance(dev, Identifies) else type(dev).__name__
        out.update(self._extra)
        return out


def make_motor(od: OdriveWiring, can_log: Path | None, **can_kw: Any) -> Motor:
    """The drive from the rig file's ``odrive:`` section (CAN Simple or USB); ``can_kw`` reaches the CAN driver
    (the emulated rig hands it its loopback bus)."""
    if od.transport == "usb":
        from beambench.devices.odrive.usb_motor import OdriveUsbMotor, UsbMotorTiming

        # the rig file's watchdog timeout: armed by the driver over USB (it was the driver's default before)
        return OdriveUsbMotor(
            serial_number=od.serial_number,
            axis=od.axis,
            timing=UsbMotorTiming(watchdog_timeout_s=od.watchdog_timeout_s),
        )
    from beambench.devices.odrive.can_motor import OdriveCanMotor
    from beambench.devices.odrive.can_timing import CanMotorTiming

    return OdriveCanMotor(
        od.channel,
        od.interface,
        od.node_id,
        bitrate=od.bitrate,
        can_log=can_log,
        timing=CanMotorTiming(
            heartbeat_timeout_s=od.heartbeat_timeout_s,
            telemetry_timeout_s=od.telemetry_timeout_s,
            watchdog_timeout_s=od.watchdog_timeout_s,
        ),
        **can_kw,
    )


def rig_file_model() -> type[RigFile]:
    """The rig file's model: :class:`RigFile` plus the sections the registered streams bring."""
    extra: dict[str, Any] = {
        s.section: (s.wiring, Field(default_factory=s.wiring)) for s in DEVICE_STREAMS.values() if s.wiring is not None
    }
    return create_model("RigFile", __base__=RigFile, **extra) if extra else RigFile


def load_wiring(path: Path) -> RigFile:
    """A rig file, validated with every registered stream's section (one-line errors naming the field)."""
    return load_rig_file(path, rig_file_model())


def build_streams(rig: RigFile, markers: tuple[str, ...]) -> dict[str, Stream]:
    """Every registered stream's driver, wired by ``rig``, in registration order."""
    return {name: s.build(DeviceContext(rig, getattr(rig, s.section), markers)) for name, s in DEVICE_STREAMS.items()}


def build_device_rig(markers: tuple[str, ...], rig_file: Path | None = None, can_log: Path | None = None) -> DeviceRig:
    """The rig of real drivers against the lab's devices, wired by ``rig_file`` (default: the shipped rig.yaml);
    ``markers``: the ones the mocap is wired to (the scene's)."""
    path = Path(rig_file) if rig_file else DEFAULT_RIG_FILE
    rig = load_wiring(path)
    return DeviceRig(
        make_motor(rig.odrive, can_log),
        build_streams(rig, markers),
        "hardware",
        extra_identity={"rig_file": path.read_text()},
    )
