"""The emulated rig: the hardware rig (:mod:`beambench.backends.hardware`) built with loopback wiring. Every
registered device stream's emulated peer (Motive on UDP loopback, the load-cell MCU on a pseudo-terminal, ...) and
an ODrive on a two-ended CAN bus over loopback UDP (:mod:`beambench.emulators.canbus`) run in a process of their
own, driven in real time by the MuJoCo physics of the sim scene; the drivers are built by the same registered
factories as on the bench, from a rig file whose addresses, ports and paths are the peers'.
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
from collections.abc import Iterator, Mapping
from multiprocessing.connection import Connection
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from beambench.acquisition.capabilities import DeviceFault
from beambench.acquisition.forces.loadcell_calibration import LoadCellCalibration, default_calibration
from beambench.acquisition.protocol.scenes import scene_info
from beambench.acquisition.protocol.schema import RigFile
from beambench.backends.hardware import DeviceRig, build_streams, make_motor, rig_file_model
from beambench.devices.peer import EmulatedPeer, GoesSilent, PeerContext, StillPhysics, Wiring
from beambench.devices.streams import DEVICE_STREAMS
from beambench.sim.protocol_slice import SimSlice

PHYSICS_THREAD = "emulated-physics"


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

    @property
    def markers(self) -> tuple[str, ...]:
        return tuple(self.scene.markers)

    @property
    def t0(self) -> float:
        """The host monotonic time (s) of scene time 0: the physics' time is now when :meth:`start` is called."""
        return self._t0

    def start(self) -> None:
        self._t0 = time.monotonic() - float(self.scene.physics.time)
        self._thread = threading.Thread(target=self._run, name=PHYSICS_THREAD, daemon=True)
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


def wired(base: RigFile, sections: Mapping[str, Mapping[str, Any]]) -> RigFile:
    """``base`` (any rig file: its timeouts and settings) with the fields of ``sections`` set (the peers' addresses,
    ports and paths), validated as a rig file with every registered stream's section."""
    data = base.model_dump()
    for name, fields in sections.items():
        data[name] = {**data.get(name, {}), **fields}
    return rig_file_model().model_validate(data)


def injections() -> tuple[str, ...]:
    """The fault-injection keys of every registered stream's peer."""
    return tuple(key for s in DEVICE_STREAMS.values() for key in s.injections)


def start_peers(ctx: PeerContext) -> tuple[dict[str, EmulatedPeer], Wiring]:
    """Every registered stream's emulated peer, opened (not sending yet), and the rig-file sections that reach
    them. A peer that cannot open closes the ones before it."""
    peers: dict[str, EmulatedPeer] = {}
    wiring: Wiring = {}
    try:
        for name, stream in DEVICE_STREAMS.items():
            if stream.peer is None:
                continue
            peers[name] = stream.peer(ctx)
            for section, fields in peers[name].open().items():
                wiring.setdefault(section, {}).update(fields)
    except BaseException:
        close_peers(peers)
        raise
    return peers, wiring


def close_peers(peers: Mapping[str, EmulatedPeer]) -> None:
    """Stop every peer (the last opened first), then close them."""
    for peer in reversed(list(peers.values())):
        with contextlib.suppress(Exception):
            peer.stop()
    for peer in reversed(list(peers.values())):
        with contextlib.suppress(Exception):
            peer.close()


@contextlib.contextmanager
def emulated_peers() -> Iterator[RigFile]:
    """Start every registered peer (at rest: :class:`StillPhysics`) and an ODrive on the python-can virtual bus,
    in this process; yields the rig wiring that reaches them (``beambench devices --emulate`` pings it)."""
    from beambench.emulators.odrive_can import EmulatedOdrive

    channel = f"beambench-{uuid.uuid4().hex[:8]}"
    odrive = EmulatedOdrive(channel=channel)
    odrive.start()
    try:
        peers, wiring = start_peers(PeerContext(StillPhysics(tuple(RigFile().natnet.markers))))
        try:
            for peer in peers.values():
                peer.start()
            yield wired(RigFile(), {**wiring, "odrive": {"interface": "virtual", "channel": channel}})
        finally:
            close_peers(peers)
    finally:
        odrive.stop()


def _favour_device_threads() -> None:
    """Real devices have CPUs of their own: give the emulators' threads (light: they format and send frames) a
    higher scheduling priority, where the OS allows it (root or CAP_SYS_NICE; without the privilege they keep the
    default). The physics (heavy) is not raised: on a 2-core machine it would starve the acquisition process,
    whose ODrive watchdog feed must keep to 0.5 s."""
    for t in threading.enumerate():
        if t is threading.main_thread() or t.name == PHYSICS_THREAD or t.native_id is None:
            continue
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, t.native_id, -10)


@dataclasses.dataclass(frozen=True)
class PeerSpec:
    """What the peers' process is started with (the first message on its socket)."""

    sim: SimSlice
    """The physics driving the peers, and their clocks, noise and seed."""
    inject: dict[str, Any]
    """Faults to inject (keys in :func:`injections`)."""
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
    streams: dict[str, EmulatedPeer] = dataclasses.field(default_factory=dict)
    """Each registered stream's peer, by stream name."""
    started: bool = False


def _make_peers(spec: PeerSpec) -> tuple[_Peers, Wiring]:
    """The ODrive and every registered stream's peer, driven by the realtime physics of ``spec.sim``; the peers
    are opened (their rig-file sections returned), not sending yet."""
    from beambench.emulators.canbus import LoopbackCanBus
    from beambench.emulators.odrive_can import EmulatedOdrive, OdriveEmulatorConfig

    sim = spec.sim
    odrive_bus = LoopbackCanBus(0, peer_port=spec.can_port)  # the ODrive's end of the rig's bus (loopback)
    try:
        config = odrive_config(scene_info(sim.scene).own_motor, spec.rig_file, OdriveEmulatorConfig)
        odrive = EmulatedOdrive(channel=odrive_bus.channel_info, config=config, bus=odrive_bus)
        peers = _Peers(odrive_bus, odrive, config, RealtimePhysics(sim, None))
        ctx = PeerContext(
            peers.physics, sim.clocks, sim.settings.seed, sim.settings.noise, spec.inject, spec.calibration
        )
        peers.streams, wiring = start_peers(ctx)
    except BaseException:
        odrive_bus.shutdown()
        raise
    return peers, wiring


def _peer_main(conn: Connection, spec: PeerSpec) -> None:
    """The emulated peers' process: the ODrive, every registered stream's peer and the realtime physics driving
    them.

    Tells the parent where to find them (``ready``), starts on ``start``, answers ``snapshot`` and ``outage``
    while running, and on ``stop`` stops everything and sends back what it injected (a report).
    """
    peers, wiring = _make_peers(spec)
    try:
        ready = {
            "wiring": wiring,  # the rig-file sections that reach the peers
            "markers": peers.physics.markers,
            "scene": peers.physics.scene.identity(),
            "odrive_config": dataclasses.asdict(peers.config),  # the motor the emulated ODrive plays
            "can_port": peers.odrive_bus.port,  # the host's end accepts frames from this port only
        }
        conn.send(("ready", ready))
        _serve(conn, peers)
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


def _serve(conn: Connection, peers: _Peers) -> None:
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
            for peer in peers.streams.values():
                peer.start()
            _favour_device_threads()
            conn.send(("started", None))
        elif cmd == "snapshot":
            conn.send(("snapshot", peers.odrive.snapshot()))
        elif cmd == "outage":
            name, seconds = arg
            silent = peers.streams.get(name)
            if not isinstance(silent, GoesSilent):
                conn.send(("error", f"no peer of stream {name!r} can go silent"))
                continue
            silent.outage(float(seconds))
            conn.send(("outage", None))
        elif cmd == "stop":
            return


def _stop_peers(conn: Connection, peers: _Peers) -> None:
    """Stop every peer, then send the parent what they injected (the report) and close the socket."""
    for peer in reversed(list(peers.streams.values())):  # the senders first; the physics after the report
        with contextlib.suppress(Exception):
            peer.stop()
    with contextlib.suppress(Exception):
        peers.odrive.stop()
    with contextlib.suppress(Exception):
        peers.odrive_bus.shutdown()
    report: dict[str, Any] = {"streams": {}}
    for name, peer in peers.streams.items():
        with contextlib.suppress(Exception):
            report["streams"][name] = peer.report()
    report["odrive"] = peers.odrive.snapshot()
    report["physics_error"] = repr(peers.physics.error) if peers.physics.error else ""
    close_peers(peers.streams)
    with contextlib.suppress(Exception):
        conn.send(("report", report))
    with contextlib.suppress(Exception):
        conn.close()
    with contextlib.suppress(Exception):
        peers.physics.stop()


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

    After :meth:`stop`, what each stream's peer reported is in ``reported[<stream>]`` (``reported["mocap"]
    .dropped_frames``, ``reported["loadcells"].injected.garbage_bursts``), and ``odrive.snapshot()`` is the ODrive
    as it stopped.
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
        self.reported: dict[str, SimpleNamespace] = {}
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

    def outage(self, stream: str, seconds: float) -> None:
        """The peer of ``stream`` sends nothing for ``seconds`` from now (a real silence on its wire)."""
        self._ask("outage", (stream, seconds))

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
                self.reported = {name: _namespace(r) for name, r in self.report["streams"].items()}


def _namespace(report: Mapping[str, Any]) -> SimpleNamespace:
    """A peer's report with attribute access, one level down too (``injected.garbage_bursts``)."""
    return SimpleNamespace(**{k: _namespace(v) if isinstance(v, Mapping) else v for k, v in report.items()})


def odrive_config(own_motor: bool, rig_file: Path | None, config_type: Any) -> Any:
    """The emulated ODrive's boot configuration: for a scene with its own motor (the walker), the motor of the rig file's ``walker:`` section
    (default: the shipped ``calibration/rig.yaml``; pole pairs, Hall feedback, torque constant, rotor + offset-mass
    inertia); the emulator's default motor for the other rigs. ``vel_limit``/``current_lim`` come from the
    protocol's limits through Set_Limits, as on the bench."""
    if not own_motor:
        return config_type(calibration_s=0.2)
    from beambench.backends.hardware import DEFAULT_RIG_FILE, load_wiring

    drive = load_wiring(rig_file or DEFAULT_RIG_FILE).walker
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
    """The hardware rig wired to emulated peers: every registered stream's peer and an ODrive, all driven by the
    MuJoCo physics, run in a process of their own (started here; they start sending when the rig opens); the
    drivers are built by the registered factories (:func:`beambench.backends.hardware.build_streams`) from
    ``wiring`` (timeouts and settings, as in a rig file) with the peers' addresses, ports and paths.

    ``inject`` sets faults (keys in :func:`injections`); the peers report exactly what they injected when they
    stop (``rig.peers[0].reported["mocap"].dropped_frames``, ``["loadcells"].injected``).
    """
    inject = dict(inject or {})
    unknown = sorted(set(inject) - set(injections()))
    if unknown:
        raise ValueError(f"unknown injections {unknown}; known: {list(injections())}")
    from beambench.emulators.canbus import LoopbackCanBus

    bus = LoopbackCanBus(0)  # the host's end, on loopback: the peers learn its port, it learns theirs
    try:
        peers = PeerProcess(PeerSpec(sim, inject, calibration or default_calibration(), bus.port, rig_file))
    except BaseException:
        bus.shutdown()
        raise
    try:
        ready = peers.ready
        bus.connect(int(ready["can_port"]))
        odrive = {"transport": "can", "interface": "loopback", "channel": bus.channel_info, "node_id": 0}
        rig = wired(wiring or RigFile(), {**ready["wiring"], "odrive": odrive})
        markers = tuple(ready["markers"])  # the scene's own markers (release test: stage, tip1..tip3)
        streams = build_streams(rig, markers)
        motor = make_motor(rig.odrive, can_log, bus=bus, own_bus=True)
    except BaseException:
        peers.stop()
        bus.shutdown()
        raise
    return DeviceRig(
        motor,
        streams,
        "emulated",
        peers=[peers],
        extra_identity={
            "emulated": {"scene": ready["scene"], "can_channel": bus.channel_info, "peers": "own process (spawn)"}
        },
    )
