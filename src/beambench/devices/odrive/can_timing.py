"""How the CAN driver times the ODrive: its liveness timeouts, the arming waits and the periods of its feeder
(:class:`CanMotorTiming`)."""

from __future__ import annotations

from dataclasses import dataclass

# The ODrive sends its heartbeat every axis.config.can.heartbeat_rate_ms, 100 ms by default, and
# Encoder_Estimates every encoder_rate_ms, 10 ms by default (firmware 0.5.x: CANConfig_t in
# Firmware/MotorControl/axis.hpp; CAN protocol docs, https://docs.odriverobotics.com/v/0.5.6/can-protocol.html,
# "cyclic messages"). A timeout of ten heartbeat periods outlasts a busy host's scheduling hiccups (a 573 ms gap
# was seen on a loaded 2-core machine) while a dead link is still noticed within a second; the ODrive's own
# watchdog (armed over USB, watchdog_timeout_s) is what idles the motor when the host stops. The rig file sets
# it (odrive.heartbeat_timeout_s).
HEARTBEAT_TIMEOUT_S = 1.0


@dataclass(frozen=True)
class CanMotorTiming:
    """How :class:`OdriveCanMotor` arms and watches the axis: calibration, the waits, the liveness timeouts and the
    periods of its watchdog feeder and poller (seconds)."""

    calibrate: bool = True  # run the full calibration sequence when arming
    calibration_timeout_s: float = 30.0
    closed_loop_timeout_s: float = 2.0
    heartbeat_timeout_s: float = HEARTBEAT_TIMEOUT_S  # no heartbeat this long: a fault
    telemetry_timeout_s: float | None = 1.0  # no Encoder_Estimates this long while streaming: a fault (None: off)
    feed_period_s: float = 0.05  # watchdog feed
    poll_period_s: float = 0.05  # bus voltage / current requests
    watchdog_timeout_s: float | None = None  # the ODrive's own watchdog (set over USB; the rig file says it)
    idle_confirm_s: float = 0.5  # how long the idle waits for a heartbeat saying AXIS_STATE_IDLE
