"""The runner of a ``track:`` protocol: each step is a profile segment whose frequency the speed controller picks.

Same life cycle and safety as :class:`~beambench.acquisition.runner.Runner` (arm, steps, idle on every exit
path), but a step is not one frequency: every ``control_s`` of rig time the runner lets the rig run, hands the
batches to the hub (the controller reads the mocap from it), asks :class:`~beambench.acquisition.control.speed_controller.
TrackController` for the next frequency, commands it and writes the decision to the ``track`` stream. The
session's ``/steps`` row of a segment carries its feed-forward frequency; ``t_settled`` marks the end of
``track.settle_s``. Losing mocap is handled by the controller (hold, then stand); a loss longer than
``max_pause_s`` ends the run as a device fault. Nothing is computed ahead (the schedule depends on the data).
"""

from __future__ import annotations

from beambench.acquisition.batch import StepRecord
from beambench.acquisition.capabilities import DeviceFault, MotorLimits, Rig
from beambench.acquisition.control.speed_controller import (
    HOLDING,
    LOST,
    MODES,
    TRACKING,
    TrackController,
    decisions_batch,
)
from beambench.acquisition.hub import Hub
from beambench.acquisition.protocol.plan import Step
from beambench.acquisition.runner import ProgressCallback, Runner, wait_polls
from beambench.acquisition.stop_signals import StopSignal


class TrackRunner(Runner):
    """Runs the segments ``steps`` (targets ``targets_mm_s``) under ``controller`` on ``rig``."""

    step_word = "segment"

    def __init__(
        self,
        rig: Rig,
        hub: Hub,
        steps: list[Step],
        limits: MotorLimits,
        controller: TrackController,
        targets_mm_s: list[float],
        on_progress: ProgressCallback | None = None,
        max_pause_s: float = 30.0,
        stop: StopSignal | None = None,
    ) -> None:
        super().__init__(
            rig, hub, steps, limits, controller.c.control_s, on_progress, None, max_pause_s=max_pause_s, stop=stop
        )
        if len(targets_mm_s) != len(steps):
            raise ValueError("one target per segment")
        self.controller, self.targets = controller, list(targets_mm_s)
        self._mode = TRACKING
        self._lost_at: int | None = None
        self._last_cmd: float | None = None

    def schedule(self) -> list[tuple[float, list[float]]]:
        return []  # closed loop: the frequencies depend on the data, nothing can be computed ahead

    def _check_steps(self) -> None:
        for s, v in zip(self.steps, self.targets):
            if v != 0 and self.controller.map.band_for(v, self.limits.max_frequency_hz) is None:
                raise DeviceFault(
                    f"{self._name(s)}: {v:g} mm/s is out of reach below {self.limits.max_frequency_hz} Hz"
                )

    def _run_step(self, step: Step) -> None:
        clock, ctl = self.rig.clock, self.controller
        target = self.targets[step.index]
        ff = ctl.set_target(target, step.index)
        rec = StepRecord(step.index, ff, clock.now_ns())
        band = "stand (0 Hz)" if ctl.band is None else f"band {ctl.band.index} {ctl.band.describe()}"
        self._begin_step(rec, f"{self._name(step)}: {target:+g} mm/s, {band}, feed-forward {ff:.2f} Hz")
        self._ticks(step.settle_s, step)
        rec.t_settled_ns = clock.now_ns()
        self._ticks(step.record_s, step)
        self._end_step(rec)

    def _ticks(self, seconds: float, step: Step) -> None:
        """Control ticks for ``seconds`` of rig time: run, read, decide, command, log."""
        motor, ctl = self.rig.motor, self.controller
        for dt in wait_polls(seconds, self.poll_s):
            self._check_stop()
            self._poll(dt)
            d = ctl.update(self.rig.clock.now_ns())
            if d.frequency_hz != self._last_cmd:
                motor.set_frequency(d.frequency_hz)
                self._last_cmd = d.frequency_hz
            self.hub.write(decisions_batch([d]))
            self._note_mode(d.mode, d.t_ns, step)
            if self.on_progress:
                self.on_progress(step.index, d.frequency_hz, dt)

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
