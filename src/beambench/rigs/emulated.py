"""The emulated rig: the real drivers against wire-level emulated peers on this machine (Motive on UDP
loopback, an ODrive on a python-can virtual bus, the load-cell MCU on a pseudo-terminal), all driven in real
time by the MuJoCo physics of the sim scene.
"""

from __future__ import annotations

import contextlib
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from beambench.acquisition.batch import Frame
from beambench.acquisition.calibration import LoadCellCalibration, default_calibration
from beambench.acquisition.config import (
    LoadCellWiring,
    NatNetWiring,
    OdriveWiring,
    Protocol,
    RigFile,
)
from beambench.rigs.hardware import DeviceRig


class RealtimePhysics:
    """Runs the sim scene at the wall clock in a thread; the emulators sample its latest rows.

    Every ``period_s`` it reads the emulated ODrive's crank speed, sets it as the scene's speed and advances
    the physics to now, feeding the crank torque back to the ODrive model. ``sample()`` returns the newest
    row no later than ``now - lag_s`` (the physics is always computed that far).
    """

    def __init__(self, protocol: Protocol, odrive: Any, period_s: float = 0.005, lag_s: float = 0.03) -> None:
        from beambench.rigs.sim import build_scene

        self.scene = build_scene(protocol)
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
        set_frequency = getattr(self.scene, "set_frequency", None)
        if set_frequency is not None:
            set_frequency(speed)
            ramp = getattr(self.scene, "ramp", None)
            if ramp is not None:
                ramp.omega = speed
        traj = self.scene.advance_to(t_target)
        if not len(traj):
            return
        force = traj.channels.get("force_nt", np.zeros((len(traj), 2)))
        motor_torque = getattr(self.scene, "motor_torque", None)
        if motor_torque is not None and self.odrive is not None:
            with contextlib.suppress(KeyError):
                self.odrive.load_torque_nm = float(motor_torque(traj.channels)[-1])
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

    def _row(self) -> int:
        t_now = time.monotonic() - self._t0 - self.lag_s
        i = int(np.searchsorted(self._t, t_now, side="right")) - 1
        return max(0, min(i, len(self._t) - 1))

    def positions(self, t: float) -> np.ndarray:
        with self._lock:
            return self._markers[self._row()].copy()

    def force(self, t: float) -> tuple[float, float]:
        with self._lock:
            fn, ft = self._force[self._row()]
        return float(fn), float(ft)


@contextlib.contextmanager
def emulated_peers(protocol: Protocol | None = None, physics: bool = False) -> Iterator[RigFile]:
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
                    natnet=NatNetWiring(
                        server_address="127.0.0.1",
                        local_address="127.0.0.1",
                        command_port=motive.command_address[1],
                        multicast=False,
                    ),
                    odrive=OdriveWiring(interface="virtual", channel=channel),
                    loadcell=LoadCellWiring(port=port),
                )
            finally:
                mcu.close()
        finally:
            motive.stop()
    finally:
        odrive.stop()


class _EmulatedPeers:
    """Starts and stops the emulators and the physics thread in the order the rig needs them."""

    def __init__(self, physics: RealtimePhysics, odrive: Any, motive: Any, mcu: Any) -> None:
        self.physics, self.odrive, self.motive, self.mcu = physics, odrive, motive, mcu

    def start(self) -> None:
        self.odrive.start()
        self.physics.odrive = self.odrive
        self.physics.start()
        self.motive.start()
        self.mcu.start()

    def stop(self) -> None:
        for peer in (self.mcu, self.motive, self.physics, self.odrive):
            with contextlib.suppress(Exception):
                peer.stop()
        with contextlib.suppress(Exception):
            self.mcu.close()


INJECTIONS = ("mocap_drop", "mocap_occlude", "loadcell_crc", "loadcell_drop", "loadcell_garbage")


def odrive_config(protocol: Protocol, rig_file: Path | None, config_type: Any) -> Any:
    """The emulated ODrive's boot configuration: for the walker, the motor of the rig file's ``walker:`` section
    (default: the shipped ``calibration/rig.yaml``; pole pairs, Hall feedback, torque constant, rotor + offset-mass
    inertia); the emulator's default motor for the other rigs. ``vel_limit``/``current_lim`` come from the
    protocol's limits through Set_Limits, as on the bench."""
    if protocol.rig != "walker":
        return config_type(calibration_s=0.2)
    from beambench.acquisition.config import load_rig_file
    from beambench.rigs.hardware import DEFAULT_RIG_FILE

    drive = load_rig_file(rig_file or DEFAULT_RIG_FILE).walker
    return config_type(
        calibration_s=0.2,
        pole_pairs=drive.pole_pairs,
        feedback=drive.feedback,
        torque_constant=drive.torque_constant_nm_a,
        # the offset mass's inertia arrives with the scene's rotor torque (fed back as the load torque); that torque
        # also carries the rotor's own inertia, so the ramp sees it twice (≈ 3 mN·m at 50 turn/s², ≈ 0.1 A)
        inertia=drive.rotor_inertia_kg_m2,
        vel_gain=0.01,
        vel_integrator_gain=0.1,
        viscous_friction=0.0,
        # no-load current × torque constant (datasheet lines 3, 12: 144 mA × 25.5 mN·m/A); it also holds the idle
        # rotor against the offset mass's weight (3.9 mN·m), which the kinematic scene would otherwise spin up
        coulomb_friction=drive.torque_constant_nm_a * 0.144,
    )


def build_emulated_rig(
    protocol: Protocol,
    can_log: Path | None = None,
    rig_file: Path | None = None,
    calibration: LoadCellCalibration | None = None,
    inject: dict[str, Any] | None = None,
) -> DeviceRig:
    """Real drivers against emulated Motive, ODrive and load-cell MCU, all driven by the MuJoCo physics.

    ``inject`` sets fault probabilities per frame (keys in :data:`INJECTIONS`); the emulators record exactly
    what they injected (``rig.peers[0].motive.dropped_frames``, ``.mcu.injected``).
    """
    inject = dict(inject or {})
    unknown = sorted(set(inject) - set(INJECTIONS))
    if unknown:
        raise ValueError(f"unknown injections {unknown}; known: {list(INJECTIONS)}")
    from beambench.devices.loadcell import SerialLoadCells
    from beambench.devices.natnet import NatNetConfig, NatNetMocap
    from beambench.devices.odrive_can import OdriveCanMotor
    from beambench.emulators.loadcell_mcu import EmulatedLoadCellMCU
    from beambench.emulators.motive import (
        MOTIVE_GEOMETRY,
        EmulatorClock,
        MotiveEmulator,
        motive_frame,
    )
    from beambench.emulators.odrive_can import EmulatedOdrive, OdriveEmulatorConfig

    sim = protocol.sim
    channel = f"beambench-{uuid.uuid4().hex[:8]}"
    odrive = EmulatedOdrive(channel=channel, config=odrive_config(protocol, rig_file, OdriveEmulatorConfig))
    physics = RealtimePhysics(protocol, None)
    markers = tuple(physics.scene.markers)  # the scene's own markers (release test: stage, tip1..tip3)
    motive = MotiveEmulator(
        marker_names=markers,
        positions=motive_frame(physics.positions),
        command_port=0,
        multicast=False,
        clock=EmulatorClock.from_model(sim.mocap_clock),
        seed=sim.seed,
        drop=inject.get("mocap_drop"),
        occlude=inject.get("mocap_occlude"),
    )
    mcu = EmulatedLoadCellMCU(
        force=physics.force,
        calibration=calibration or default_calibration(),
        drift_ppm=sim.loadcell_clock.drift_ppm,
        noise_counts=50.0 if sim.noise else 0.0,
        seed=sim.seed,
        crc_error_prob=inject.get("loadcell_crc", 0.0),
        drop_prob=inject.get("loadcell_drop", 0.0),
        garbage_prob=inject.get("loadcell_garbage", 0.0),
    )
    port = mcu.open()
    peers = _EmulatedPeers(physics, odrive, motive, mcu)

    class _LateMocap(NatNetMocap):
        """The Motive emulator picks its port on start; point the client at it then."""

        def start(self) -> None:
            self.config.command_port = motive.command_address[1]
            super().start()

    mocap = _LateMocap(
        markers,
        NatNetConfig(server_address="127.0.0.1", local_address="127.0.0.1", command_port=0, multicast=False),
        frame=Frame(**MOTIVE_GEOMETRY),
    )
    motor = OdriveCanMotor(channel, "virtual", 0, can_log=can_log)
    loadcells = SerialLoadCells(port)
    return DeviceRig(
        motor,
        mocap,
        loadcells,
        "emulated",
        peers=[peers],
        extra_identity={"emulated": {"scene": physics.scene.identity(), "can_channel": channel}},
    )
