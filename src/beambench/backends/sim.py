"""The sim backend's :class:`~beambench.acquisition.capabilities.Rig`: a MuJoCo scene plus simulated devices.

``rig.clock.wait(s)`` advances the physics by ``s`` (paced to the wall clock with ``realtime``); after each
chunk every device samples the new trajectory rows on its own clock.

With ``prefetch`` the next chunk (same length, same command) is computed on a worker thread while the caller
stores the last one (MuJoCo releases the GIL); a command or a different wait undoes it from a snapshot, so
the data are identical with and without prefetch. Once the runner announces the run's schedule
(:meth:`SimRig.anticipate`), a worker computes the whole script ahead instead (:mod:`beambench.backends.lookahead`;
same data), and with ``sim.segments: n`` (walker, contact rig) n workers compute consecutive parts of the sweep in
parallel, each later part pre-settled at its first frequency (what that changes, and the contact rig's check of
each cut: the lookahead module's docstring).
"""

from __future__ import annotations

import contextlib
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, cast

import mujoco
import numpy as np

from beambench.acquisition.capabilities import DeviceFault, Stream, WarnsOfModel
from beambench.acquisition.protocol.schema import ConfigError
from beambench.acquisition.streams import LOADCELL, MOCAP, MOTOR, MOTOR_RATE_HZ
from beambench.backends import lookahead
from beambench.backends.sim_devices import SampledStream, SimClock, SimMotor
from beambench.backends.sim_streams import SIM_STREAMS, SimStreamContext
from beambench.sim import scenes
from beambench.sim.engine.stepping import Trajectory, quiet_mujoco_warnings
from beambench.sim.models.registry import UnknownModelError, beam_model
from beambench.sim.protocol_slice import SimSlice
from beambench.sim.scenes import SceneConfig
from beambench.sim.scenes.drive import ChecksCuts, CostsByFrequency, DrivenScene, VelocityRamp, WarmsUp

HISTORY_S = 0.02  # rows kept from earlier chunks (for interpolation and the load cells' boxcar)
# the order the streams' noise seeds are drawn in (these three's from before streams were registered, so a seed
# gives the same noise as it did); the other registered streams follow by name
SEED_ORDER = (MOCAP, LOADCELL, MOTOR)


def build_scene(sim: SimSlice) -> DrivenScene:
    """The MuJoCo scene of ``sim`` (the scene registry's builder), its beam made from the slice's model and set."""
    try:
        beam = beam_model(sim.model, sim.params)
    except UnknownModelError as exc:
        raise ConfigError("<protocol>", "sim.model", sim.model, str(exc).split(": ", 1)[-1]) from None
    return scenes.get(sim.scene).build(SceneConfig(beam, sim))


class SimRig:
    """Clock, motor and streams of a simulated rig (``Rig`` protocol)."""

    def __init__(
        self, sim: SimSlice, realtime: bool = False, scene: DrivenScene | None = None, prefetch: bool = True
    ) -> None:
        self.sim = sim
        noise = sim.settings.noise
        # MuJoCo's warnings from the build (its preroll) to close() are collected, not printed: a diverging state
        # stops the run in check()
        self._quiet = contextlib.ExitStack()
        self._warnings: list[str] = self._quiet.enter_context(quiet_mujoco_warnings())
        try:
            self.scene = scene or build_scene(sim)
        except BaseException:
            self._quiet.close()
            raise
        names = [*SEED_ORDER, *sorted(set(SIM_STREAMS) - set(SEED_ORDER))]
        seeds = np.random.SeedSequence(sim.settings.seed).spawn(len(names))
        rngs = {name: np.random.default_rng(s) for name, s in zip(names, seeds, strict=True)}
        self.clock = SimClock(self._advance, realtime=realtime)
        ctx = SimStreamContext(sim, tuple(self.scene.markers), rngs)
        self.named: dict[str, SampledStream] = {name: make(ctx) for name, make in SIM_STREAMS.items()}
        rig = self.scene.rig
        self.motor = SimMotor(
            ctx.clock(MOTOR, MOTOR_RATE_HZ),
            self.scene.ramp,
            self.scene.motor_torque,
            self._command,
            ctx.rng(MOTOR),
            torque_constant=rig.torque_constant,
            bus_voltage=rig.bus_voltage,
            noise=noise,
            now=lambda: self.clock.now_ns() * 1e-9,
        )
        self.motor.amplitude_mm = None if sim.stage_amplitude_m is None else sim.stage_amplitude_m * 1e3
        self._devices: list[SampledStream] = [self.motor, *self.named.values()]
        self.streams: list[Stream] = list(self._devices)
        self._hist: Trajectory | None = None
        self._state = "new"
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="sim-prefetch") if prefetch else None
        self._ahead: tuple[int, Future, tuple] | None = None  # (target ns, job, snapshot to undo it)
        self._last_ns = 0
        self._own_scene = scene is None  # segments need copies of the scene, built from the slice
        self._look: lookahead.Lookahead | None = None
        self._look_info: dict[str, Any] | None = None
        self._scenes: list[DrivenScene] = [self.scene]  # every scene built (segments), closed at the end
        self._offset = {"x": 0.0, "theta": 0.0}  # added to the rows once a later segment's scene took over

    def __getattr__(self, name: str) -> SampledStream:
        """A simulated stream by its name (``rig.mocap``, ``rig.loadcell``)."""
        named = self.__dict__.get("named", {})
        if name in named:
            return named[name]
        raise AttributeError(f"{type(self).__name__} has no attribute or stream {name!r}")

    def open(self) -> None:
        if self._state != "new":
            return
        self.clock.reset()
        self._hist = self.scene.advance_to(0.0)
        for dev in self._devices:
            dev.start()
            dev.ingest(self._hist, 0.0)
        self._state = "open"

    def close(self) -> None:
        if self._state == "closed":
            return
        try:
            self.motor.idle()
        finally:
            if self._look is not None:
                self._look.stop()
                self._look = None
            self._undo_ahead()
            if self._pool is not None:
                self._pool.shutdown(wait=True)
            for dev in self._devices:
                dev.stop()
            for scene in self._scenes:
                scene.physics.close()
            self._quiet.close()
            self._state = "closed"

    # --- lookahead ------------------------------------------------------------------------------------
    def anticipate(self, schedule: list[tuple[float, list[float]]]) -> None:
        """The run's schedule (``Anticipates``): compute it ahead on worker threads (with prefetch only)."""
        if self._state != "open" or self._pool is None or self._look is not None or not schedule:
            return
        self._undo_ahead()
        calls = lookahead.script(schedule, self.clock.now_ns(), int(self.clock.max_chunk_s * 1e9))
        segments = self.sim.segments if self._own_scene else 1
        cost = self.scene.step_cost if isinstance(self.scene, CostsByFrequency) else None
        cuts = lookahead.cut_points(calls, segments, lookahead.PRESETTLE_S, cost)
        clones = [build_scene(self.sim) for _ in cuts]
        self._scenes += clones
        if isinstance(self.scene, ChecksCuts):  # each cut checked; the rig does not walk: no marker offset
            self._look = lookahead.Lookahead(
                self.scene, calls, cuts, clones, walk_axis=None, agree=self.scene.same_regime
            )
        else:
            self._look = lookahead.Lookahead(self.scene, calls, cuts, clones)

    def _drop_lookahead(self) -> None:
        """The run left the script: stop the workers, continue from the state after the last call taken."""
        look = self._look
        if look is None:
            return
        self._look = None
        snap = look.stop()
        if look.scene is not self.scene:  # a later segment's scene holds the state now
            self.scene = look.scene
            self._offset = dict(look.offset)
            self.motor.ramp = cast(VelocityRamp, _ShiftedRamp(self.scene.ramp, self._offset["theta"]))
        self.scene.restore(snap if snap is not None else look.start)
        if len(look.segments) > 1:
            self._look_info = lookahead.info(look)

    def computed_ahead(self) -> tuple[float, int] | None:
        """How far the workers have computed the announced run (``ReportsComputedAhead``): every segment's share."""
        look = self._look
        return None if look is None else lookahead.computed(look)

    def model_warnings(self) -> list[str]:
        """The scene's own (``WarnsOfModel``): e.g. the physical twin's walker on legs that fold."""
        return self.scene.model_warnings() if isinstance(self.scene, WarnsOfModel) else []

    def after_run(self) -> dict[str, Any]:
        """``sim_segments`` in ``/general`` when the sweep was cut into segments, the beam's final thermal state
        with ``sim.thermal_drift`` (``ReportsAfterRun``)."""
        if self._look is not None and len(self._look.segments) > 1:
            self._look_info = lookahead.info(self._look)
        out: dict[str, Any] = {"sim_segments": self._look_info} if self._look_info else {}
        if isinstance(self.scene, WarmsUp) and self.scene.thermal is not None:
            out["sim_thermal_drift"] = self.scene.thermal.now()
        return out

    # --- stepping -------------------------------------------------------------------------------------
    def _command(self, hz: float) -> None:
        """Motor → scene: a new crank-speed setpoint takes effect from the current time."""
        if self._look is not None:
            if self._look.expects("cmd", self.clock.now_ns(), hz):
                self._look.take(self._hist)
                return
            self._drop_lookahead()
        self._undo_ahead()
        self.scene.set_frequency(hz)

    def _undo_ahead(self) -> None:
        if self._ahead is not None:
            _, job, snap = self._ahead
            self._ahead = None
            job.result()
            self.scene.restore(snap)

    def _advance(self, now_ns: int) -> None:
        if self._state != "open":
            raise RuntimeError("sim rig: clock.wait() before open() or after close()")
        now = now_ns * 1e-9
        if self._look is not None and not self._look.expects("adv", now_ns):
            self._drop_lookahead()
        if self._look is not None:
            new = self._look.take(self._hist)
            assert new is not None
        elif self._ahead is not None and self._ahead[0] == now_ns:
            new = lookahead.shifted(self._ahead[1].result(), self._offset, 0)
            self._ahead = None
        else:
            self._undo_ahead()
            new = lookahead.shifted(self.scene.advance_to(now), self._offset, 0)
        if len(new):
            old = self._hist
            keep = old.t >= new.t[0] - HISTORY_S if old is not None else None
            self._hist = (
                new
                if old is None
                else Trajectory.concat([Trajectory(old.t[keep], {k: v[keep] for k, v in old.channels.items()}), new])
            )
        assert self._hist is not None  # open() made the first rows
        for dev in self._devices:
            dev.ingest(self._hist, now)
        step_ns, self._last_ns = now_ns - self._last_ns, now_ns
        if self._pool is not None and step_ns > 0 and self._look is None:
            target = now_ns + step_ns
            snap = self.scene.snapshot()
            self._ahead = (target, self._pool.submit(self.scene.advance_to, target * 1e-9), snap)

    def check(self) -> None:
        """The physics, the motor, then every stream (the simulated devices never go silent; the same call as on a
        rig). Physics that diverged (MuJoCo's bad-acceleration reset, or a non-finite state) is a device fault:
        the runner idles the motor and saves what was recorded."""
        self._check_physics()
        for device in self.streams:
            device.check()

    def _check_physics(self) -> None:
        diverged = next((w for w in self._warnings if "nan" in w.lower() or "inf" in w.lower()), None)
        if diverged is None and self._hist is not None and len(self._hist):
            last = self._hist.tail(1)
            if not all(np.isfinite(v).all() for v in last.channels.values()):
                diverged = "a non-finite value in the state"
        if diverged is not None:
            t = self.clock.now_ns() * 1e-9
            raise DeviceFault(
                f"sim: the physics diverged by t = {t:.3f} s (MuJoCo: {' '.join(diverged.split())[:120]}); "
                "check the parameter set and sim.timestep"
            )

    def identity(self) -> dict[str, Any]:
        sim = self.sim
        return {
            "backend": "sim",
            "rig": sim.scene,
            "model": self.scene.identity(),
            "mujoco_version": mujoco.__version__,
            "seed": sim.settings.seed,
            "noise": sim.settings.noise,
            "devices": {name: dev.about() for name, dev in (("motor", self.motor), *self.named.items())},
        }


class _ShiftedRamp:
    """The motor's view of a later segment's ramp: its angle continues the first scene's (``SimMotor.idle``)."""

    def __init__(self, ramp: Any, theta_offset: float) -> None:
        self._ramp, self._dtheta = ramp, theta_offset

    @property
    def theta(self) -> float:
        return float(self._ramp.theta) + self._dtheta

    def __getattr__(self, name: str) -> Any:
        return getattr(self._ramp, name)


def build_sim_rig(sim: SimSlice, realtime: bool = False, prefetch: bool = True) -> SimRig:
    """The sim backend's rig for a protocol's simulation slice (contact rig, walker or release test)."""
    return SimRig(sim, realtime=realtime, prefetch=prefetch)
