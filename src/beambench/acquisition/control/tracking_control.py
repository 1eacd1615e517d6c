"""Speed tracking as the runner's per-step strategy: each step is a profile segment whose frequency the speed
controller picks every poll (:class:`~beambench.acquisition.step_control.StepControl`).

Every ``control_s`` of rig time the runner lets the rig run and hands the batches to the hub (the controller, a
hub sink, reads the mocap from it); :meth:`SpeedTracking.tick` asks
:class:`~beambench.acquisition.control.speed_controller.TrackController` for the next frequency and writes the
decision to the ``track`` stream. The session's ``/steps`` row of a segment carries its feed-forward frequency;
``t_settled`` marks the end of ``track.settle_s``. Losing mocap is handled by the controller (hold, then stand),
with ``pause``, ``stand`` and ``resume`` events; a loss longer than ``max_pause_s`` ends the run as a device fault.
"""

from __future__ import annotations

from beambench.acquisition.capabilities import DeviceFault, MotorLimits
from beambench.acquisition.control.speed_controller import (
    HOLDING,
    LOST,
    MODES,
    TRACKING,
    TrackController,
    decisions_batch,
)
from beambench.acquisition.hub import Hub
from beambench.acquisition.protocol.plan import Step, step_name
from beambench.acquisition.step_control import StepStart


class SpeedTracking:
    """Segments with targets ``targets_mm_s`` (one per step) under ``controller``; decisions and events to ``hub``."""

    closed_loop = True

    def __init__(self, controller: TrackController, targets_mm_s: list[float], hub: Hub, max_pause_s: float) -> None:
        self.controller, self.targets, self.hub = controller, list(targets_mm_s), hub
        self.max_pause_s = max_pause_s
        self._mode = TRACKING
        self._lost_at: int | None = None

    def _name(self, step: Step) -> str:
        """The segment in words: ``segment 3 of 6 (index 2)``."""
        return step_name(step.index, len(self.targets), "segment")

    def check(self, steps: list[Step], limits: MotorLimits) -> None:
        if len(self.targets) != len(steps):
            raise ValueError("one target per segment")
        for s, v in zip(steps, self.targets):
            if v != 0 and self.controller.map.band_for(v, limits.max_frequency_hz) is None:
                raise DeviceFault(f"{self._name(s)}: {v:g} mm/s is out of reach below {limits.max_frequency_hz} Hz")

    def start(self, step: Step, now_ns: int) -> StepStart:
        ctl = self.controller
        target = self.targets[step.index]
        ff = ctl.set_target(target, step.index)
        band = "stand (0 Hz)" if ctl.band is None else f"band {ctl.band.index} {ctl.band.describe()}"
        message = f"{self._name(step)}: {target:+g} mm/s, {band}, feed-forward {ff:.2f} Hz"
        return StepStart(ff, None, message)  # the first poll's decision is the first command

    def tick(self, step: Step, now_ns: int) -> float:
        d = self.controller.update(now_ns)
        self.hub.write(decisions_batch([d]))
        self._note_mode(d.mode, d.t_ns, step)
        return d.frequency_hz

    def _note_mode(self, mode: int, now: int, step: Step) -> None:
        """Events when the mocap is lost (pause), the walker stood for it, and the mocap returned (resume)."""
        if mode == self._mode:
            if (
                mode in (HOLDING, LOST)
                and self._lost_at is not None
                and (now - self._lost_at) * 1e-9 > self.max_pause_s
            ):
                raise DeviceFault(f"mocap lost for longer than monitors.max_pause_s = {self.max_pause_s:g} s")
            return
        if mode in (HOLDING, LOST) and self._mode not in (HOLDING, LOST):
            self._lost_at = now
            self.hub.event(now, "pause", f"{self._name(step)}: {MODES[mode]} at {self.controller.f_cmd:.2f} Hz")
        elif mode == LOST:
            self.hub.event(now, "stand", f"{self._name(step)}: {MODES[mode]} (0 Hz)")
        elif self._mode in (HOLDING, LOST):
            gone = (now - (self._lost_at or now)) * 1e-9
            self.hub.event(now, "resume", f"{self._name(step)}: mocap back after {gone:.2f} s")
            self._lost_at = None
        self._mode = mode
