"""The emulated rig: the real drivers against wire-level emulated peers on this machine (Motive on UDP
loopback, an ODrive on a two-ended CAN bus over loopback UDP (:mod:`beambench.emulators.canbus`), the load-cell MCU on a pseudo-terminal), all driven in real
time by the MuJoCo physics of the sim scene.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Collection, Iterator
from multiprocessing.connection import Connection
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from beambench.acquisition.batch import Frame
from beambench.acquisition.capabilities import DeviceFault
from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration, default_calibration
from beambench.acquisition.protocol.scenes import scene_info
from beambench.acquisition.protocol.schema import (
    LoadCellWiring,
    NatNetWiring,
    OdriveWiring,
    RigFile,
)
from beambench.acquisition.streams import LOADCELL, MOCAP
from beambench.backends.hardware import DeviceRig
from beambench.sim.protocol_slice import SimSlice


class RealtimePhysics:
    """Runs the sim scene at the wall clock in a thread; the emulators sample its latest rows.

    Every ``period_s`` it reads the emulated ODrive's crank speed, sets it as the scene's speed and advances
    the physics to now, feeding the crank torque back to the ODrive model. The load cells sample the newest row
    no later than ``now - lag_s`` (the physics is always computed that far); the mocap samples each frame at its
    own exposure time less ``lag_s`` (:meth:`positions_at`), so a frame sent late (the emulator's thread was not
    scheduled for tens of ms under load) still carries the markers of its timestamp.
    """

    def __init__(self, sim: SimSlice, odrive: Any, period_s: float = 0.005, lag_s: float = 0.03) -> None:
        from beambench.backends.sim import build_scene

        self.scene = build_scene(sim)
        self.odrive = odrive
        self.period_s, self.lag_s = period_s, lag_s
        self._lock = threading.Lock()
        self._t = np.zeros(0)
        self._markers = np.zeros((0, len(self.scene.markers), 3))
        self._force = np.zeros((0, 2))
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._t0 = 0.0
        self.error: BaseException | None = None
        self.advance(0.05)

    def start(self) -> None:
        self._t0 = time.monotonic() - float(self.scene.physics.time)
        self._thread = threading.Thread(target=self._run, name="emulated-physics", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2)

    def advance(self, t_target: float) -> None:
        speed = float(self.odrive.velocity_turns_s) if self.odrive is not None else 0.0
        self.scene.set_frequency(speed)  # every scene is a DrivenScene: a crank speed, its ramp, a motor torque
        self.scene.ramp.omega = speed
        traj = self.scene.advance_to(t_target)
        if not len(traj):
            return
        force = traj.channels.get("force_nt", np.zeros((len(traj), 2)))
        if self.odrive is not None:
            with contextlib.suppress(KeyError):
                self.odrive.load_torque_nm = float(self.scene.motor_torque(traj.channels)[-1])
        with self._lock:
            keep = self._t[-2000:] if len(self._t) else self._t
            k = len(keep)
            self._t = np.concatenate([keep, traj.t])
            self._markers = np.concatenate([self._markers[len(self._markers) - k :], traj.channels["markers"]])
            self._force = np.concatenate([self._force[len(self._force) - k :], force])

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self.advance(time.monotonic() - self._t0)
                self._stop.wait(self.period_s)
        except BaseException as exc:  # reported through sample(), which the emulators call
            self.error = exc

    def _row(self, host_s: float | None = None) -> int:
        """The newest row no later than ``host_s`` (host monotonic, default now) less ``lag_s``."""
        t = (time.monotonic() if host_s is None else host_s) - self._t0 - self.lag_s
        i = int(np.searchsorted(self._t, t, side="right")) - 1
        return max(0, min(i, len(self._t) - 1))

    def positions(self, t: float) -> np.ndarray:
        """The markers now (less ``lag_s``); ``t`` is ignored."""
        with self._lock:
            return self._markers[self._row()].copy()

    def positions_at(self, host_s: float) -> np.ndarray:
        """The markers at host monotonic time ``host_s`` less ``lag_s`` (the newest row if not computed yet)."""
        with self._lock:
            return self._markers[self._row(host_s)].copy()

    def force(self, t: float) -> tuple[float, float]:
        with self._lock:
            fn, ft = self._force[self._row()]
        return float(fn), float(ft)


@contextlib.contextmanager
def emulated_peers() -> Iterator[RigFile]:
    """Start the three emulated peers on loopback/virtual bus/pty; yields the rig wiring that reaches them."""
    from beambench.emulators.loadcell_mcu import EmulatedLoadCellMCU
    from beambench.emulators.motive import MotiveEmulator
    from beambench.emulators.odrive_can import EmulatedOdrive

    channel = f"beambench-{uuid.uuid4().hex[:8]}"
    odrive = EmulatedOdrive(channel=channel)
    motive = MotiveEmulator(command_port=0, multicast=False, wait_for_client=False)
    mcu = EmulatedLoadCellMCU()
    odrive.start()
    try:
        motive.start()
        try:
            port = mcu.open()
            mcu.start()
            try:
                yield RigFile(
                    natnet=NatNetWiring.model_validate(
                        {
                            "server_address": "127.0.0.1",
                            "local_address": "127.0.0.1",
                            "command_port": motive.command_address[1],
                            "multicast": False,
                        }
                    ),
                    odrive=OdriveWiring.model_validate({"interface": "virtual", "channel": channel}),
                    loadcell=LoadCellWiring.model_validate({"port": port}),
                )
            finally:
                mcu.close()
        finally:
            motive.stop()
    finally:
        odrive.stop()


INJECTIONS = (
    "mocap_drop",  # a probability per frame, or the frame numbers to drop
    "mocap_occlude",  # a probability per marker and frame, or {frame number: marker indices}
    "loadcell_crc",
    "loadcell_drop",
    "loadcell_garbage",
    "loadcell_stop_s",  # the load-cell board stops sending this many seconds after the rig opened
)


class _Outage:
    """Motive frame filter: every frame is dropped from ``start()`` for ``seconds`` (a real UDP silence), and the
    frames numbered in ``base`` (the injected drops) always."""

    def __init__(self, base: Collection[int] | None) -> None:
        self.base = frozenset(base or ())
        self.t0: float | None = None
        self.seconds = 0.0

    def start(self, seconds: float) -> None:
        self.seconds, self.t0 = seconds, time.monotonic()

    def __call__(self, number: int) -> bool:
        if self.t0 is not None and time.monotonic() - self.t0 < self.seconds:
            return True
        return number in self.base


DEVICE_THREADS = ("motive-", "loadcell-mcu", "odrive-emulator")


def _favour_device_threads() -> None:
    """Real devices have CPUs of their own: give the emulators' threads (light: they format and send frames) a
    higher scheduling priority, where the OS allows it (root or CAP_SYS_NICE; without the privilege they keep the
    default). The physics (heavy) is not raised: on a 2-core machine it would starve the acquisition process,
    whose ODrive watchdog feed must keep to 0.5 s."""
    for t in threading.enumerate():
        if t.native_id is not None and t.name.startswith(DEVICE_THREADS):
            with contextlib.suppress(OSError):
                os.setpriority(os.PRIO_PROCESS, t.native_id, -10)


@dataclasses.dataclass(frozen=True)
class PeerSpec:
    """What the peers' process is started with (the first message on its socket)."""

    sim: SimSlice
    """The physics driving the peers, and their clocks, noise and seed."""
    inject: dict[str, Any]
    """Faults to inject (keys in :data:`INJECTIONS`)."""
    calibration: LoadCellCalibration
    """The load-cell MCU's calibration (counts per newton)."""
    can_port: int
    """The host's end of the loopback CAN bus."""
    rig_file: Path | None = None
    """The rig file whose ``walker:`` motor the emulated ODrive plays (None: the shipped one)."""


def _peer_entry(fd: int) -> None:
    """Entry point of the peers' process: the first message on the socket ``fd`` is the :class:`PeerSpec`.
    Signals are the acquisition process's business (it stops the peers when it is done); a parent that dies
    closes the socket, which ends this process."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    conn = Connection(fd)
    try:
        spec = conn.recv()
    except EOFError:
        return
    try:
        _peer_main(conn, spec)
    except BaseException as exc:  # building the peers failed (the physics' compile out of memory …): one line
        with contextlib.suppress(BaseException):
            conn.send(("error", _failure(exc)))


@dataclasses.dataclass
class _Peers:
    """The emulators of one peers' process and the physics driving them."""

    odrive_bus: Any
    odrive: Any
    config: Any
    physics: RealtimePhysics
    motive: Any
    mcu: Any
    outage: _Outage
    started: bool = False
    stop_mcu: threading.Timer | None = None


def _make_peers(spec: PeerSpec) -> _Peers:
    """Motive, the ODrive and the load-cell MCU, driven by the realtime physics of ``spec.sim``."""
    from beambench.emulators.canbus import LoopbackCanBus
    from beambench.emulators.loadcell_mcu import EmulatedLoadCellMCU, LinkFaults, McuClock
    from beambench.emulators.motive import EmulatorClock, MotiveEmulator, motive_frame
    from beambench.emulators.odrive_can import EmulatedOdrive, OdriveEmulatorConfig

    inject, sim = spec.inject, spec.sim
    odrive_bus = LoopbackCanBus(0, peer_port=spec.can_port)  # the ODrive's end of the rig's bus (loopback)
    config = odrive_config(scene_info(sim.scene).own_motor, spec.rig_file, OdriveEmulatorConfig)
    odrive = EmulatedOdrive(channel=odrive_bus.channel_info, config=config, bus=odrive_bus)
    physics = RealtimePhysics(sim, None)
    drop = inject.get("mocap_drop")
    outage = _Outage(None if isinstance(drop, float) else drop)
    motive: MotiveEmulator | None = None

    def exposed(t: float) -> np.ndarray:  # t: stream time of a frame, exposed at stream start + t
        if motive is None or motive.t0 is None:  # not streaming yet (the model definition asks): now
            return physics.positions(t)
        return physics.positions_at(motive.t0 + t)

    motive = MotiveEmulator(
        marker_names=tuple(physics.scene.markers),
        positions=motive_frame(exposed),
        command_port=0,
        multicast=False,
        clock=EmulatorClock.from_model(sim.clocks.of(MOCAP)),
        seed=sim.settings.seed,
        drop=drop if isinstance(drop, float) else outage,
        occlude=inject.get("mocap_occlude"),
    )
    mcu = EmulatedLoadCellMCU(
        force=physics.force,
        calibration=spec.calibration,
        clock=McuClock(drift_ppm=sim.clocks.of(LOADCELL).drift_ppm),
        noise_counts=50.0 if sim.settings.noise else 0.0,
        seed=sim.settings.seed,
        faults=LinkFaults(
            crc_error_prob=inject.get("loadcell_crc", 0.0),
            drop_prob=inject.get("loadcell_drop", 0.0),
            garbage_prob=inject.get("loadcell_garbage", 0.0),
        ),
        tx_buffer=1 << 22,  # frames the emulator sends late when its own process was starved are not lost
    )
    return _Peers(odrive_bus, odrive, config, physics, motive, mcu, outage)


def _peer_main(conn: Connection, spec: PeerSpec) -> None:
    """The emulated peers' process: Motive, the ODrive, the load-cell MCU and the realtime physics driving them.

    Tells the parent where to find them (``ready``), starts on ``start``, answers ``snapshot`` and ``outage``
    while running, and on ``stop`` stops everything and sends back what it injected (a report).
    """
    peers = _make_peers(spec)
    try:
        peers.motive.start()  # binds its ports; streams once the client connects
        lc_port = peers.mcu.open()
        ready = {
            "command_port": peers.motive.command_address[1],
            "loadcell_port": lc_port,
            "markers": tuple(peers.physics.scene.markers),
            "scene": peers.physics.scene.identity(),
            "odrive_config": dataclasses.asdict(peers.config),  # the motor the emulated ODrive plays
            "can_port": peers.odrive_bus.port,  # the host's end accepts frames from this port only
        }
        conn.send(("ready", ready))
        _serve(conn, peers, spec.inject)
    except (EOFError, OSError, KeyboardInterrupt):  # the parent went away (killed: SIGKILL, a crash)
        if peers.started:
            _await_watchdog(peers.odrive, peers.config.watchdog_timeout_s)
    except BaseException as exc:  # a peer failed (a thread that cannot start): one line to the parent, no traceback
        with contextlib.suppress(BaseException):
            conn.send(("error", _failure(exc)))
    finally:
        _stop_peers(conn, peers)


def _failure(exc: BaseException) -> str:
    """What stopped the peers, in one line: out of memory named as such."""
    from beambench.common.out_of_memory import out_of_memory

    reason = out_of_memory(exc)
    text = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else ""
    return f"out of memory ({reason})" if reason else f"{type(exc).__name__}: {text}"


def _serve(conn: Connection, peers: _Peers, inject: dict[str, Any]) -> None:
    """Answer the parent's commands until ``stop``."""
    while True:
        if not conn.poll(0.2):
            continue
        cmd, arg = conn.recv()
        if cmd == "start" and not peers.started:
            peers.started = True
            peers.odrive.start()
            peers.physics.odrive = peers.odrive
            peers.physics.start()
            peers.mcu.start()
            _favour_device_threads()
            if inject.get("loadcell_stop_s") is not None:
                peers.stop_mcu = threading.Timer(float(inject["loadcell_stop_s"]), peers.mcu.stop)
                peers.stop_mcu.daemon = True
                peers.stop_mcu.start()
            conn.send(("started", None))
        elif cmd == "snapshot":
            conn.send(("snapshot", peers.odrive.snapshot()))
        elif cmd == "outage":
            peers.outage.start(float(arg))
            conn.send(("outage", None))
        elif cmd == "stop":
            return


def _stop_peers(conn: Connection, peers: _Peers) -> None:
    """Stop every peer, then send the parent what they injected (the report) and close the socket."""
    motive, mcu, physics, odrive = peers.motive, peers.mcu, peers.physics, peers.odrive
    if peers.stop_mcu is not None:
        peers.stop_mcu.cancel()
    for peer in (mcu, motive, odrive):  # the senders first; the physics (nothing samples it now) after the report
        with contextlib.suppress(Exception):
            peer.stop()
    with contextlib.suppress(Exception):
        peers.odrive_bus.shutdown()
    report = {
        "motive": {
            "dropped_frames": list(motive.dropped_frames),
            "occlusions": list(motive.occlusions),
            "frames_sent": motive.frames_sent,
            "error": repr(motive.error) if motive.error else "",
        },
        "mcu": {
            "injected": mcu.injected.as_dict(),
            "broken_seqs": list(mcu.broken_seqs),
            "overflowed_seqs": list(mcu.overflowed_seqs),
            "error": mcu.error or "",
        },
        "odrive": odrive.snapshot(),
        "physics_error": repr(physics.error) if physics.error else "",
    }
    with contextlib.suppress(Exception):
        mcu.close()
    with contextlib.suppress(Exception):
        conn.send(("report", report))
    with contextlib.suppress(Exception):
        conn.close()
    with contextlib.suppress(Exception):
        physics.stop()


def _await_watchdog(odrive: Any, timeout_s: float) -> None:
    """The host died without idling the motor: like a real ODrive, the emulated one runs on, fed by nobody, until
    its own watchdog idles the axis (``watchdog_timeout_s``). Says on stderr (the run's) what it did and when."""
    t0 = time.monotonic()
    deadline = t0 + timeout_s + 1.0
    snap = odrive.snapshot()
    while snap["state"] != 1 and time.monotonic() < deadline:  # AXIS_STATE_IDLE
        time.sleep(0.005)
        snap = odrive.snapshot()
    after = time.monotonic() - t0
    if snap["state"] == 1:
        how = f"its watchdog idled the axis {after:.2f} s after the host was lost (axis error {snap['axis_error']:#x})"
    else:
        how = f"still in state {snap['state']} {after:.2f} s after the host was lost: its watchdog did not stop it"
    with contextlib.suppress(OSError):
        print(f"beambench: emulated ODrive: {how}", file=sys.stderr, flush=True)


class _Snapshot:
    """The emulated ODrive as the parent sees it: its boot configuration (``config``), live snapshots while the
    peers run, the last one after."""

    def __init__(self, peers: PeerProcess) -> None:
        self._peers = peers

    @property
    def config(self) -> SimpleNamespace:
        return SimpleNamespace(**self._peers.ready["odrive_config"])

    def snapshot(self) -> dict[str, Any]:
        return self._peers.odrive_snapshot()


REPORT_TIMEOUT_S = 3.0  # how long stopping the peers waits for their report
EXIT_GRACE_S = 0.5  # then for their process to end before it is killed


class PeerProcess:
    """The emulated peers in a process of their own (spawned), as real devices are: the acquisition process's
    scheduling cannot make them late, and theirs cannot make it late.

    After :meth:`stop`, what they injected is here: ``motive.dropped_frames``, ``mcu.injected``,
    ``mcu.broken_seqs``, ``mcu.overflowed_seqs``, ``odrive.snapshot()`` (as when they stopped).
    """

    def __init__(self, spec: PeerSpec, ready_timeout_s: float = 60.0) -> None:
        # a fresh interpreter (like multiprocessing's spawn, without re-importing the caller's __main__, so a
        # script or notebook needs no ``if __name__ == "__main__"`` guard), talking over a socket pair
        parent, child = socket.socketpair()
        env = dict(os.environ)
        src = str(Path(__file__).resolve().parents[2])  # this beambench, whichever checkout it is
        env["PYTHONPATH"] = os.pathsep.join([src, *filter(None, [env.get("PYTHONPATH")])])
        env.setdefault("MUJOCO_GL", "disable")  # no GLFW probe process (see beambench.cli): the peers never draw
        self._proc = subprocess.Popen(
            [
                sys.executable,
                "-c",
                f"from beambench.backends.emulated import _peer_entry; _peer_entry({child.fileno()})",
            ],
            pass_fds=(child.fileno(),),
            env=env,
            stdin=subprocess.DEVNULL,
            start_new_session=True,  # a terminal's Ctrl-C goes to the acquisition process, not to the "devices"
        )
        child.close()
        self._conn = Connection(parent.detach())
        self._lock = threading.Lock()
        self.report: dict[str, Any] | None = None
        self.odrive = _Snapshot(self)
        self.motive: Any = None
        self.mcu: Any = None
        try:
            self._conn.send(spec)
            self.ready = self._expect("ready", ready_timeout_s)
        except BaseException:
            self.stop()
            raise

    @property
    def pid(self) -> int:
        return self._proc.pid

    def _alive(self) -> bool:
        return self._proc.poll() is None

    def _lost(self) -> DeviceFault:
        """The peers' process went away (killed, crashed): one device fault saying so."""
        with contextlib.suppress(subprocess.TimeoutExpired):
            self._proc.wait(timeout=0.5)
        code = self._proc.poll()
        how = "is gone" if code is None else f"ended (exit {code})" if code >= 0 else f"was killed ({-code})"
        return DeviceFault(f"the emulated peers' process {how}")

    def _expect(self, what: str, timeout_s: float) -> Any:
        try:
            if not self._conn.poll(timeout_s):
                raise DeviceFault(f"emulated peers: no {what!r} within {timeout_s:g} s")
            kind, value = self._conn.recv()
        except (EOFError, OSError):
            raise self._lost() from None
        if kind == "error":  # a peer failed (its one line)
            raise DeviceFault(f"emulated peers: {value}")
        if kind != what:
            raise DeviceFault(f"emulated peers: expected {what!r}, got {kind!r}")
        return value

    def _ask(self, cmd: str, arg: Any = None, timeout_s: float = 10.0) -> Any:
        with self._lock:
            if self.report is not None or not self._alive():
                raise self._lost()
            try:
                self._conn.send((cmd, arg))
            except OSError:
                raise self._lost() from None
            return self._expect(cmd if cmd != "start" else "started", timeout_s)

    def start(self) -> None:
        self._ask("start")

    def mocap_outage(self, seconds: float) -> None:
        """Motive sends nothing for ``seconds`` from now (a real UDP silence)."""
        self._ask("outage", seconds)

    def odrive_snapshot(self) -> dict[str, Any]:
        if self.report is not None:
            return dict(self.report["odrive"])
        return dict(self._ask("snapshot"))

    def stop(self) -> None:
        """Stop the peers and keep their report; bounded: at most :data:`REPORT_TIMEOUT_S` for the report (the
        peers stop their senders first, then report), then :data:`EXIT_GRACE_S` for the process to end, then it is
        killed (it has stopped everything; its interpreter's teardown is not worth a run's exit waiting for it,
        nor is a peer that hangs). Idempotent."""
        with self._lock:
            if self.report is None and self._alive():
                with contextlib.suppress(Exception):
                    self._conn.send(("stop", None))
                    deadline = time.monotonic() + REPORT_TIMEOUT_S
                    while self.report is None and self._conn.poll(max(0.0, deadline - time.monotonic())):
                        kind, value = self._conn.recv()
                        if kind == "report":
                            self.report = value
            try:
                self._proc.wait(timeout=EXIT_GRACE_S)
            except subprocess.TimeoutExpired:
                self._proc.kill()  # SIGKILL: ends even a stopped (SIGSTOP) process
                with contextlib.suppress(subprocess.TimeoutExpired):
                    self._proc.wait(timeout=2.0)
            with contextlib.suppress(Exception):
                self._conn.close()
            if self.report is not None:
                from beambench.emulators.loadcell_mcu import Injected

                m, c = self.report["motive"], self.report["mcu"]
                self.motive = SimpleNamespace(**m)
                self.mcu = SimpleNamespace(**{**c, "injected": Injected(**c["injected"])})


def odrive_config(own_motor: bool, rig_file: Path | None, config_type: Any) -> Any:
    """The emulated ODrive's boot configuration: for a scene with its own motor (the walker), the motor of the rig file's ``walker:`` section
    (default: the shipped ``calibration/rig.yaml``; pole pairs, Hall feedback, torque constant, rotor + offset-mass
    inertia); the emulator's default motor for the other rigs. ``vel_limit``/``current_lim`` come from the
    protocol's limits through Set_Limits, as on the bench."""
    if not own_motor:
        return config_type(calibration_s=0.2)
    from beambench.acquisition.protocol.schema import load_rig_file
    from beambench.backends.hardware import DEFAULT_RIG_FILE

    drive = load_rig_file(rig_file or DEFAULT_RIG_FILE).walker
    return config_type(
        calibration_s=0.2,
        pole_pairs=drive.pole_pairs,
        feedback=drive.feedback,
        torque_constant=drive.torque_constant_nm_a,
        # the offset mass's inertia arrives with the scene's rotor torque (fed back as the load torque); that torque
        # also carries the rotor's own inertia, so the ramp sees it twice (≈ 12 mN·m at 200 turn/s², ≈ 0.5 A)
        inertia=drive.rotor_inertia_kg_m2,
        vel_ramp_rate=drive.vel_ramp_rate_turn_s2,
        vel_gain=0.01,
        vel_integrator_gain=0.1,
        viscous_friction=0.0,
        # no-load current × torque constant (datasheet lines 3, 12: 144 mA × 25.5 mN·m/A); it also holds the idle
        # rotor against the offset mass's weight (3.9 mN·m), which the kinematic scene would otherwise spin up
        coulomb_friction=drive.torque_constant_nm_a * 0.144,
    )


def build_emulated_rig(
    sim: SimSlice,
    can_log: Path | None = None,
    rig_file: Path | None = None,
    calibration: LoadCellCalibration | None = None,
    inject: dict[str, Any] | None = None,
    wiring: RigFile | None = None,
) -> DeviceRig:
    """Real drivers against emulated Motive, ODrive and load-cell MCU, all driven by the MuJoCo physics, which
    run in a process of their own (started here; they start sending when the rig opens).

    ``inject`` sets faults (keys in :data:`INJECTIONS`); the peers report exactly what they injected when they
    stop (``rig.peers[0].motive.dropped_frames``, ``.mcu.injected``). ``wiring`` gives the drivers' settings
    (heartbeat and silence timeouts) as in a rig file; addresses and ports are the emulators'.
    """
    inject = dict(inject or {})
    unknown = sorted(set(inject) - set(INJECTIONS))
    if unknown:
        raise ValueError(f"unknown injections {unknown}; known: {list(INJECTIONS)}")
    from beambench.devices.loadcell.driver import SerialLoadCells
    from beambench.devices.natnet.client import NatNetConfig
    from beambench.devices.natnet.mocap import NatNetMocap
    from beambench.devices.odrive.can_motor import OdriveCanMotor
    from beambench.devices.odrive.can_timing import CanMotorTiming
    from beambench.emulators.canbus import LoopbackCanBus
    from beambench.emulators.motive import MOTIVE_GEOMETRY

    wiring = wiring or RigFile()
    bus = LoopbackCanBus(0)  # the host's end, on loopback: the peers learn its port, it learns theirs
    try:
        peers = PeerProcess(PeerSpec(sim, inject, calibration or default_calibration(), bus.port, rig_file))
    except BaseException:
        bus.shutdown()
        raise
    try:
        ready = peers.ready
        bus.connect(int(ready["can_port"]))
        markers = tuple(ready["markers"])  # the scene's own markers (release test: stage, tip1..tip3)
        mocap = NatNetMocap(
            markers,
            NatNetConfig(
                server_address="127.0.0.1",
                local_address="127.0.0.1",
                command_port=int(ready["command_port"]),
                multicast=False,
            ),
            frame=Frame(**MOTIVE_GEOMETRY),
            silence_timeout_s=wiring.natnet.silence_timeout_s,
        )
        channel = bus.channel_info
        motor = OdriveCanMotor(
            channel,
            "loopback",
            0,
            bus=bus,
            own_bus=True,
            can_log=can_log,
            timing=CanMotorTiming(
                heartbeat_timeout_s=wiring.odrive.heartbeat_timeout_s,
                telemetry_timeout_s=wiring.odrive.telemetry_timeout_s,
                watchdog_timeout_s=wiring.odrive.watchdog_timeout_s,
            ),
        )
        loadcells = SerialLoadCells(ready["loadcell_port"], silence_timeout_s=wiring.loadcell.silence_timeout_s)
    except BaseException:
        peers.stop()
        bus.shutdown()
        raise
    return DeviceRig(
        motor,
        {"mocap": mocap, "loadcells": loadcells},
        "emulated",
        peers=[peers],
        extra_identity={"emulated": {"scene": ready["scene"], "can_channel": channel, "peers": "own process (spawn)"}},
    )
