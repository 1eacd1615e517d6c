"""``beambench devices``' look at an ODrive on a CAN bus: listen for heartbeats, ask one node for its voltage,
errors and position. Never moves anything."""

from __future__ import annotations

import time
from typing import Any

import can

from beambench.common.oserrors import can_open_problem
from beambench.devices.odrive import cansimple as cs
from beambench.devices.odrive.cansimple import AxisState


def ping(
    channel: str = "can0",
    interface: str = "socketcan",
    node_id: int | None = None,
    *,
    bitrate: int | None = None,
    listen_s: float = 0.35,
    bus: can.BusABC | None = None,
) -> dict[str, Any]:
    """Listen on a CAN bus for ODrive heartbeats and ask the node (``node_id``, or the first heard) for its
    bus voltage, errors and encoder estimates. Never moves anything; never raises for a silent bus.

    Returns ``found``, ``nodes`` (every node id heard), ``heartbeat_hz``, ``axis_state``, ``axis_error``,
    ``bus_voltage_v``, ``position_turn`` and errors; CAN Simple 0.5.x cannot report serial or firmware.
    """
    info: dict[str, Any] = {
        "device": "ODrive v3.6 (CAN Simple, fw 0.5.x)",
        "interface": interface,
        "channel": channel,
        "found": False,
    }
    own = bus is None
    try:
        if bus is None:
            kw: dict[str, Any] = {"interface": interface, "channel": channel}
            if bitrate is not None:
                kw["bitrate"] = bitrate
            bus = can.Bus(**kw)
    except Exception as exc:
        info["error"] = can_open_problem(interface, channel, exc, bitrate)
        return info
    try:
        beats: dict[int, list[tuple[float, cs.Heartbeat]]] = {}
        replies: dict[str, Any] = {}
        target = node_id

        def listen(seconds: float) -> None:
            end = time.monotonic() + seconds
            while (left := end - time.monotonic()) > 0:
                frame = bus.recv(timeout=left)
                if frame is None:
                    continue
                try:
                    node, msg = cs.parse_message(frame)
                except cs.CanParseError:
                    continue
                if isinstance(msg, cs.Heartbeat):  # the frame's own stamp: when it was on the bus, not when read
                    beats.setdefault(node, []).append((frame.timestamp or time.time(), msg))
                elif node == target and isinstance(msg, cs.BusVoltageCurrent):
                    replies["bus_voltage_v"] = round(msg.voltage, 3)
                elif node == target and isinstance(msg, cs.EncoderEstimates):
                    replies["position_turn"] = round(msg.pos, 4)
                elif node == target and isinstance(msg, cs.MotorError):
                    replies["motor_error"] = msg.error
                elif node == target and isinstance(msg, cs.EncoderError):
                    replies["encoder_error"] = msg.error
                elif node == target and isinstance(msg, cs.ControllerErrorMsg):
                    replies["controller_error"] = msg.error

        listen(listen_s)
        if target is None and beats:
            target = min(beats)
        if target is not None and target in beats:
            for cmd in (
                cs.Cmd.GET_BUS_VOLTAGE_CURRENT,
                cs.Cmd.GET_ENCODER_ESTIMATES,
                cs.Cmd.GET_MOTOR_ERROR,
                cs.Cmd.GET_ENCODER_ERROR,
                cs.Cmd.GET_CONTROLLER_ERROR,
            ):
                bus.send(cs.request(target, cmd))
            listen(0.15)
        info["nodes"] = sorted(beats)
        if target is not None:
            info["node_id"] = target
        if target is not None and target in beats:
            hbs = beats[target]
            last = hbs[-1][1]
            state = last.axis_state
            info.update(
                found=True,
                axis_error=cs.error_names(last.axis_error),
                **replies,
                axis_state=AxisState(state).name if state in AxisState._value2member_map_ else state,
            )
            if len(hbs) > 1:
                info["heartbeat_hz"] = round((len(hbs) - 1) / (hbs[-1][0] - hbs[0][0]), 1)
    except Exception as exc:
        info["error"] = str(exc)
    finally:
        if own:
            bus.shutdown()
    return info
