"""An emulated ODrive v3.6 axis (firmware 0.5.x) speaking CAN Simple on a python-can bus, in a thread.

Use it with python-can's in-process virtual bus: the driver and the emulator each open
``can.Bus(interface="virtual", channel=X)`` on the same ``X`` and talk through real frames::

    with EmulatedOdrive(channel="bench", config=OdriveEmulatorConfig(calibration_s=0.3)) as odrv:
        with OdriveCanMotor(channel="bench", interface="virtual") as motor:
            motor.arm(limits)
            ...

What is emulated (:class:`OdriveAxisModel`, pure, driven by explicit time; :class:`EmulatedOdrive` binds it
to a bus):

* state machine: IDLE → FULL_CALIBRATION_SEQUENCE (or MOTOR_CALIBRATION / ENCODER_OFFSET_CALIBRATION) for
  ``calibration_s`` → IDLE; CLOSED_LOOP_CONTROL only once calibrated (else ``INVALID_STATE``) and only in
  velocity control (the boot default is position control, so a host must set the controller mode; any other
  mode → controller ``INVALID_INPUT_MODE``); any error → IDLE; non-idle requests are ignored while an error
  is latched (as on the firmware) until Clear_Errors.
* velocity control: ``VEL_RAMP`` ramps the setpoint at ``vel_ramp_rate`` (turn/s², a USB-only setting),
  setpoint clamped to ``vel_limit``, a PI velocity loop whose current is clamped to ``current_lim``, a
  rotor + crank inertia with viscous and Coulomb friction and an optional load torque from the physics.
  Overspeed (|vel| > vel_limit × vel_limit_tolerance) → controller ``OVERSPEED`` → IDLE.
* watchdog: in non-idle states, no frame addressed to the axis for ``watchdog_timeout_s`` →
  ``WATCHDOG_TIMER_EXPIRED`` → IDLE. Any frame to the node feeds it, as on the firmware.
* Estop → ``ESTOP_REQUESTED`` → IDLE; Clear_Errors; Reboot (silent for ``reboot_s``, then boot defaults);
  Set_Axis_Node_ID; injectable motor/encoder/controller errors.
* cyclic Heartbeat (100 ms) and Encoder_Estimates (10 ms); RTR (or DLC-0) gets answered: motor, encoder and
  controller error, encoder estimates, Iq, bus voltage and current. Heartbeat RTRs are ignored (as 0.5.x).

Not emulated: position/torque control, trajectories, sensorless and encoder counts, the current loop.
The crank angle and speed (``position_turns``, ``velocity_turns_s``) and ``load_torque_nm`` are exposed so
the MuJoCo physics can follow (or load) the crank.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import can

from beambench.devices.odrive import cansimple as cs
from beambench.devices.odrive.cansimple import (
    AxisError,
    AxisState,
    ControllerError,
    ControlMode,
    InputMode,
)

CALIBRATION_STATES = (
    AxisState.FULL_CALIBRATION_SEQUENCE,
    AxisState.MOTOR_CALIBRATION,
    AxisState.ENCODER_OFFSET_CALIBRATION,
)
TWO_PI = 2.0 * math.pi
HW_MAX_CURRENT = 60.0  # A; the ODrive v3.6 cannot drive more whatever current_lim says


@dataclass(frozen=True)
class OdriveEmulatorConfig:
    """Boot configuration of the emulated axis (what the real one would have saved via USB)."""

    node_id: int = 0
    calibration_s: float = 0.5  # a real full calibration takes ~10 s
    calibrated: bool = False  # motor calibrated and encoder ready at boot (pre_calibrated + index)
    watchdog_timeout_s: float = 0.5  # axis.config.watchdog_timeout; 0 = enable_watchdog False
    vel_limit: float = 2.0  # turn/s, the firmware default
    vel_limit_tolerance: float = 1.2
    enable_overspeed_error: bool = True
    current_lim: float = 10.0  # A, the firmware default
    vel_ramp_rate: float = 100.0  # turn/s² (controller.config.vel_ramp_rate; not settable over CAN Simple)
    vel_gain: float = 0.05  # N·m/(turn/s)
    vel_integrator_gain: float = 0.5  # N·m/(turn/s·s)
    torque_constant: float = 0.04  # N·m/A (8.27 / KV)
    inertia: float = 1e-4  # kg·m², rotor + crank
    pole_pairs: int = 7  # motor.config.pole_pairs (reported; the model is torque-level, commutation is not modelled)
    feedback: str = "encoder"  # encoder mode: "encoder" (incremental + index) or "hall" (the motor's Hall sensors)
    viscous_friction: float = 1e-4  # N·m/(turn/s)
    coulomb_friction: float = 2e-3  # N·m
    bus_voltage: float = 24.0  # V at no load
    supply_resistance: float = 0.05  # Ω, bus sag under load
    heartbeat_ms: int = 100
    encoder_ms: int = 10
    reboot_s: float = 0.2
    max_step_s: float = 0.001  # physics sub-step


class OdriveAxisModel:
    """One ODrive axis: state machine, controller and mechanics. Not thread-safe; time is passed in (s)."""

    def __init__(self, config: OdriveEmulatorConfig = OdriveEmulatorConfig(), t: float = 0.0) -> None:
        self.boot_config = config
        self.parse_errors = 0
        self.received = 0
        self._boot(t)
        self.position = 0.0
        self.velocity = 0.0

    # ------------------------------------------------------------------ lifecycle
    def _boot(self, t: float) -> None:
        c = self.boot_config
        self.cfg = c
        self.node_id = c.node_id
        self.state = AxisState.IDLE
        self.axis_error = 0
        self.motor_error = 0
        self.encoder_error = 0
        self.controller_error = 0
        self.motor_calibrated = c.calibrated
        self.encoder_ready = c.calibrated
        self.control_mode: int = ControlMode.POSITION_CONTROL  # firmware boot default (any int off the wire)
        self.input_mode: int = InputMode.PASSTHROUGH
        self.vel_limit = c.vel_limit
        self.current_lim = c.current_lim
        self.input_vel = 0.0
        self.torque_ff = 0.0
        self.vel_setpoint = 0.0
        self.integrator = 0.0
        self.iq_setpoint = 0.0
        self.iq_measured = 0.0
        self.bus_current = 0.0
        self.load_torque = 0.0
        self.t = t
        self.state_until = math.inf
        self.last_feed = t
        self.silent_until = -math.inf
        self.transitions: list[tuple[float, int]] = [(t, int(self.state))]

    # ------------------------------------------------------------------ state machine
    def _set_state(self, state: AxisState) -> None:
        if state != self.state:
            self.state = state
            self.transitions.append((self.t, int(state)))
        if state == AxisState.IDLE:
            self.iq_setpoint = self.iq_measured = 0.0
            self.integrator = 0.0
            self.state_until = math.inf

    def _fail(self, bit: int) -> None:
        self.axis_error |= bit
        self._set_state(AxisState.IDLE)

    def request_state(self, requested: int) -> None:
        """Set_Axis_State."""
        if requested == AxisState.IDLE:
            self._set_state(AxisState.IDLE)
            return
        if self.axis_error:
            return  # latched error: the state machine stays idle until Clear_Errors
        if requested in CALIBRATION_STATES:
            if requested == AxisState.ENCODER_OFFSET_CALIBRATION and not self.motor_calibrated:
                self._fail(AxisError.INVALID_STATE)
                return
            self._set_state(AxisState(requested))
            frac = 0.4 if requested != AxisState.FULL_CALIBRATION_SEQUENCE else 1.0
            self.state_until = self.t + self.cfg.calibration_s * frac
        elif requested == AxisState.CLOSED_LOOP_CONTROL:
            if not (self.motor_calibrated and self.encoder_ready):
                self._fail(AxisError.INVALID_STATE)
                return
            if self.control_mode != ControlMode.VELOCITY_CONTROL:
                self.controller_error |= ControllerError.INVALID_INPUT_MODE
                self._fail(AxisError.CONTROLLER_FAILED)
                return
            self._set_state(AxisState.CLOSED_LOOP_CONTROL)
            self.vel_setpoint = self.velocity
            self.integrator = 0.0
            self.last_feed = self.t
        else:
            self._fail(AxisError.INVALID_STATE)  # not emulated

    def _finish_calibration(self) -> None:
        if self.state in (AxisState.FULL_CALIBRATION_SEQUENCE, AxisState.MOTOR_CALIBRATION):
            self.motor_calibrated = True
        if self.state in (AxisState.FULL_CALIBRATION_SEQUENCE, AxisState.ENCODER_OFFSET_CALIBRATION):
            self.encoder_ready = True
        self._set_state(AxisState.IDLE)

    def inject_error(self, motor: int = 0, encoder: int = 0, controller: int = 0, axis: int = 0) -> None:
        """Latch sub-component errors as the firmware would (sets MOTOR/ENCODER/CONTROLLER_FAILED)."""
        bits = axis
        if motor:
            self.motor_error |= motor
            bits |= AxisError.MOTOR_FAILED
        if encoder:
            self.encoder_error |= encoder
            bits |= AxisError.ENCODER_FAILED
        if controller:
            self.controller_error |= controller
            bits |= AxisError.CONTROLLER_FAILED
        if bits:
            self._fail(bits)

    # ------------------------------------------------------------------ time
    def advance(self, t: float) -> None:
        """Integrate the axis up to time ``t`` (s) in sub-steps of at most ``max_step_s``."""
        while self.t < t:
            dt = min(self.cfg.max_step_s, t - self.t)
            if self.state_until <= self.t + dt:  # calibration ends inside this step
                dt = max(self.state_until - self.t, 0.0)
                self._step(dt)
                self._finish_calibration()
                continue
            self._step(dt)
        if (
            self.state != AxisState.IDLE
            and self.cfg.watchdog_timeout_s > 0
            and t - self.last_feed > self.cfg.watchdog_timeout_s
        ):
            self._fail(AxisError.WATCHDOG_TIMER_EXPIRED)

    def _step(self, dt: float) -> None:
        c = self.cfg
        self.t += dt
        if self.state == AxisState.CLOSED_LOOP_CONTROL:
            target = self.input_vel
            if self.input_mode == InputMode.VEL_RAMP:
                step = c.vel_ramp_rate * dt
                self.vel_setpoint += min(max(target - self.vel_setpoint, -step), step)
            else:
                self.vel_setpoint = target
            self.vel_setpoint = min(max(self.vel_setpoint, -self.vel_limit), self.vel_limit)
            err = self.vel_setpoint - self.velocity
            torque = c.vel_gain * err + self.integrator + self.torque_ff
            iq = torque / c.torque_constant
            limited = abs(iq) > self.current_lim
            self.iq_setpoint = min(max(iq, -self.current_lim), self.current_lim)
            if limited:
                self.integrator *= 0.99  # the firmware's anti-windup decay
            else:
                self.integrator += c.vel_integrator_gain * err * dt
            self.iq_measured = self.iq_setpoint
        else:
            self.iq_setpoint = self.iq_measured = 0.0
        motor_torque = c.torque_constant * self.iq_measured
        friction = c.viscous_friction * self.velocity
        drive = motor_torque - self.load_torque - friction
        coulomb = c.coulomb_friction
        if abs(self.velocity) > 1e-6:
            drive -= math.copysign(coulomb, self.velocity)
        elif abs(drive) <= coulomb:
            drive = 0.0  # static friction holds
        else:
            drive -= math.copysign(coulomb, drive)
        accel = drive / (c.inertia * TWO_PI)  # turn/s²
        new_vel = self.velocity + accel * dt
        if self.velocity != 0.0 and new_vel * self.velocity < 0 and abs(motor_torque - self.load_torque) <= coulomb:
            new_vel = 0.0  # friction stops, it does not reverse
        self.velocity = new_vel
        self.position += self.velocity * dt
        power = motor_torque * self.velocity * TWO_PI
        self.bus_current = power / max(c.bus_voltage, 1e-3)
        if (
            self.state == AxisState.CLOSED_LOOP_CONTROL
            and c.enable_overspeed_error
            and abs(self.velocity) > self.vel_limit * c.vel_limit_tolerance
        ):
            self.controller_error |= ControllerError.OVERSPEED
            self._fail(AxisError.CONTROLLER_FAILED)

    @property
    def bus_voltage(self) -> float:
        return self.cfg.bus_voltage - self.cfg.supply_resistance * self.bus_current

    # ------------------------------------------------------------------ messages
    def heartbeat(self) -> cs.Heartbeat:
        return cs.Heartbeat(
            int(self.axis_error),
            int(self.state),
            self.motor_error != 0,
            self.encoder_error != 0,
            self.controller_error != 0,
            False,
        )

    def estimates(self) -> cs.EncoderEstimates:
        return cs.EncoderEstimates(self.position, self.velocity)

    def _answer(self, cmd: cs.Cmd) -> cs.Message | None:
        if cmd == cs.Cmd.GET_MOTOR_ERROR:
            return cs.MotorError(int(self.motor_error))
        if cmd == cs.Cmd.GET_ENCODER_ERROR:
            return cs.EncoderError(int(self.encoder_error))
        if cmd == cs.Cmd.GET_CONTROLLER_ERROR:
            return cs.ControllerErrorMsg(int(self.controller_error))
        if cmd == cs.Cmd.GET_ENCODER_ESTIMATES:
            return self.estimates()
        if cmd == cs.Cmd.GET_IQ:
            return cs.Iq(self.iq_setpoint, self.iq_measured)
        if cmd == cs.Cmd.GET_BUS_VOLTAGE_CURRENT:
            return cs.BusVoltageCurrent(self.bus_voltage, self.bus_current)
        return None

    def handle(self, msg: cs.Message | cs.Request) -> list[cs.Message]:
        """Apply a frame addressed to this node (already advanced to now); returns the replies."""
        self.received += 1
        self.last_feed = self.t  # every frame to the node feeds the watchdog
        if isinstance(msg, cs.Request):
            reply = self._answer(msg.cmd)
            return [reply] if reply is not None else []
        if isinstance(msg, cs.Estop):
            self._fail(AxisError.ESTOP_REQUESTED)
        elif isinstance(msg, cs.SetAxisState):
            self.request_state(msg.state)
        elif isinstance(msg, cs.SetControllerMode):
            self.control_mode = msg.control_mode
            self.input_mode = msg.input_mode
            if self.state == AxisState.CLOSED_LOOP_CONTROL and self.control_mode != ControlMode.VELOCITY_CONTROL:
                self.controller_error |= ControllerError.INVALID_INPUT_MODE
                self._fail(AxisError.CONTROLLER_FAILED)
        elif isinstance(msg, cs.SetInputVel):
            if math.isfinite(msg.vel) and math.isfinite(msg.torque_ff):  # NaN is dropped, not emulated
                self.input_vel, self.torque_ff = msg.vel, msg.torque_ff
        elif isinstance(msg, cs.SetLimits):
            if math.isfinite(msg.vel_limit) and math.isfinite(msg.current_limit):
                self.vel_limit = abs(msg.vel_limit)
                self.current_lim = min(abs(msg.current_limit), HW_MAX_CURRENT)
        elif isinstance(msg, cs.ClearErrors):
            self.axis_error = self.motor_error = self.encoder_error = self.controller_error = 0
        elif isinstance(msg, cs.SetAxisNodeId):
            if msg.node_id <= cs.MAX_NODE_ID:
                self.node_id = msg.node_id
        elif isinstance(msg, cs.Reboot):
            pos, vel, t = self.position, self.velocity, self.t
            self._boot(t)
            self.position, self.velocity = pos, vel
            self.silent_until = t + self.cfg.reboot_s
        # other messages (cyclic data of other axes, heartbeats) are ignored
        return []


class EmulatedOdrive:
    """An :class:`OdriveAxisModel` on a python-can bus, served by a background thread.

    ``bus`` may be given (it is then not shut down by :meth:`stop`); otherwise one is opened with
    ``can.Bus(interface=interface, channel=channel)``. ``clock`` returns seconds (monotonic).
    """

    def __init__(
        self,
        channel: str = "beambench-odrive",
        interface: str = "virtual",
        config: OdriveEmulatorConfig | None = None,
        *,
        bus: can.BusABC | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.channel, self.interface = channel, interface
        self.config = config or OdriveEmulatorConfig()
        self._clock = clock
        self._bus = bus
        self._own_bus = bus is None
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.model = OdriveAxisModel(self.config, clock())
        self.sent = 0
        self.error: BaseException | None = None
        self._stall: tuple[int, float] | None = None  # (command id, seconds): fault injection, see stall_after
        self.stalls = 0

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> EmulatedOdrive:
        if self._thread is not None:
            return self
        if self._bus is None:
            self._bus = can.Bus(interface=self.interface, channel=self.channel)
        with self._lock:
            self.model = OdriveAxisModel(self.config, self._clock())
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"odrive-emulator-{self.channel}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving (the bus goes silent: no more heartbeats). Idempotent."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._own_bus and self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def __enter__(self) -> EmulatedOdrive:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # ------------------------------------------------------------------ physics seam
    @property
    def position_turns(self) -> float:
        with self._lock:
            return self.model.position

    @property
    def velocity_turns_s(self) -> float:
        with self._lock:
            return self.model.velocity

    @property
    def load_torque_nm(self) -> float:
        with self._lock:
            return self.model.load_torque

    @load_torque_nm.setter
    def load_torque_nm(self, value: float) -> None:
        with self._lock:
            self.model.load_torque = float(value)

    def snapshot(self) -> dict[str, float | int]:
        """The axis' state at this instant (advanced to now)."""
        with self._lock:
            m = self.model
            m.advance(self._clock())
            return {
                "t": m.t,
                "node_id": m.node_id,
                "state": int(m.state),
                "axis_error": int(m.axis_error),
                "motor_error": int(m.motor_error),
                "encoder_error": int(m.encoder_error),
                "controller_error": int(m.controller_error),
                "position": m.position,
                "velocity": m.velocity,
                "input_vel": m.input_vel,
                "vel_setpoint": m.vel_setpoint,
                "vel_limit": m.vel_limit,
                "current_lim": m.current_lim,
                "iq": m.iq_measured,
                "control_mode": int(m.control_mode),
                "input_mode": int(m.input_mode),
                "received": m.received,
                "parse_errors": m.parse_errors,
            }

    def inject_error(self, motor: int = 0, encoder: int = 0, controller: int = 0, axis: int = 0) -> None:
        with self._lock:
            self.model.advance(self._clock())
            self.model.inject_error(motor, encoder, controller, axis)

    def stall_after(self, command: int, seconds: float) -> None:
        """Fault injection: once the next frame of ``command`` is handled, this emulator's thread gets no CPU for
        ``seconds`` (as on a loaded host); the axis's own timeline runs on meanwhile."""
        with self._lock:
            self._stall = (int(command), float(seconds))

    def configure(self, **changes: object) -> None:
        """Change configuration as if set over USB (e.g. ``watchdog_timeout_s``, ``vel_ramp_rate``)."""
        with self._lock:
            self.model.cfg = replace(self.model.cfg, **changes)  # type: ignore[arg-type]

    # ------------------------------------------------------------------ thread
    def _send(self, msg: cs.Message) -> None:
        assert self._bus is not None
        self._bus.send(cs.to_can(self.model.node_id, msg))
        self.sent += 1

    def _run(self) -> None:
        bus = self._bus
        assert bus is not None
        now = self._clock()
        next_hb = now
        next_enc = now
        try:
            while not self._stop.is_set():
                with self._lock:
                    silent_until = self.model.silent_until
                    hb_period = self.model.cfg.heartbeat_ms / 1000.0
                    enc_period = self.model.cfg.encoder_ms / 1000.0
                wake = min(next_hb, next_enc)
                timeout = min(max(0.0, wake - self._clock()), 0.05)
                frame = bus.recv(timeout=timeout)
                with self._lock:
                    now = self._clock()
                    m = self.model
                    if now >= m.silent_until:
                        next_hb, next_enc = self._late_cyclic((next_hb, hb_period), (next_enc, enc_period), now)
                    m.advance(now)
                    if frame is not None and now >= silent_until:
                        self._on_frame(frame)
                        stall = self._stall_due(frame)
                        if stall:
                            self._lock.release()  # starved: nothing runs in this thread, the lock is free
                            try:
                                time.sleep(stall)
                            finally:
                                self._lock.acquire()
                    if now < m.silent_until:
                        next_hb = next_enc = m.silent_until
                        continue
                    if now >= next_enc:
                        if enc_period > 0:
                            self._send(m.estimates())
                        next_enc = next_enc + enc_period if next_enc + enc_period > now else now + enc_period
                    if now >= next_hb:
                        if hb_period > 0:
                            self._send(m.heartbeat())
                        next_hb = next_hb + hb_period if next_hb + hb_period > now else now + hb_period
        except Exception as exc:
            if not (self._stop.is_set() and isinstance(exc, (can.CanError, OSError))):
                self.error = exc

    def _late_cyclic(self, hb: tuple[float, float], enc: tuple[float, float], now: float) -> tuple[float, float]:
        """Cyclic messages (heartbeat, encoder estimates; each ``(next due, period)``) that fell due while this
        thread got no CPU, in the order they fell due, each saying the axis's state at its own due time: a device's
        timeline (and its message rates) does not skip because its emulator was starved. The last one of each due is
        left to the caller, at ``now``. At most a second's worth; returns the next due times."""
        due = [hb[0], enc[0]]
        periods = (hb[1], enc[1])
        send = (self.model.heartbeat, self.model.estimates)
        for _ in range(sum(max(1, round(1.0 / p)) for p in periods if p > 0)):
            late = [i for i in (0, 1) if periods[i] > 0 and due[i] + periods[i] <= now]
            if not late:
                break
            i = min(late, key=lambda j: due[j])
            self.model.advance(due[i])
            self._send(send[i]())
            due[i] += periods[i]
        return due[0], due[1]

    def _stall_due(self, frame: can.Message) -> float:
        if self._stall is None:
            return 0.0
        try:
            node, cmd = cs.split_id(frame.arbitration_id, frame.is_extended_id)
        except cs.CanParseError:
            return 0.0
        if node != self.model.node_id or cmd != self._stall[0]:
            return 0.0
        seconds, self._stall = self._stall[1], None
        self.stalls += 1
        return seconds

    def _on_frame(self, frame: can.Message) -> None:
        m = self.model
        try:
            node, _cmd = cs.split_id(frame.arbitration_id, frame.is_extended_id)
        except cs.CanParseError:
            return
        if node != m.node_id:
            return
        try:
            _, msg = cs.parse_message(frame)
        except cs.CanParseError:
            m.parse_errors += 1
            m.received += 1
            m.last_feed = m.t
            return
        for reply in m.handle(msg):
            self._send(reply)
