"""One step's contacts as ``beambench analyze`` finds them, shared by the analysis and the live view's step panel.

The regime and contacts per cycle of a step come from the plate's normal force over its record window, classified
at the frequency the analysis analyses the step at (:func:`analysis_frequency`: the stage's measured frequency,
else the motor's, else the commanded). The contact rule compares flights with a tenth of a drive period, and the
force is sampled at 1 kHz: at 20 Hz a 5-sample gap is exactly that long, so the frequency and the window's times
must be the analysis's own (times from the window's start, ``(t_ns - start_ns) / 1e9``) for the live panel to say
what ``steps.csv`` says. :func:`window_contacts` is that computation on one window.
"""

from __future__ import annotations

import numpy as np

from beambench.acquisition.forces.contact_events import ContactParams, ContactSummary, force_contacts
from beambench.analysis.signals import NAN_SINE, SineFit, fit_sinusoid
from beambench.analysis.trajectory import StageFrame, stage_frame


def stage_sine(t_s: np.ndarray, stage_m: np.ndarray | None, frame: StageFrame | None, f_cmd: float) -> SineFit:
    """The stage's motion along the drive axis fitted with a sine near the commanded frequency."""
    if stage_m is None or frame is None:
        return NAN_SINE
    disp = (stage_m - np.nanmean(stage_m, axis=0)) @ frame.drive if len(stage_m) else np.zeros(0)
    return fit_sinusoid(t_s, disp, f_cmd if f_cmd > 0 else None)


def motor_frequency(velocity: np.ndarray) -> float:
    """The motor's mean speed (turn/s = Hz) over a window, NaN without telemetry."""
    return float(np.nanmean(np.abs(velocity))) if np.isfinite(velocity).any() else np.nan


def analysis_frequency(sine: SineFit, motor_hz: float, f_cmd: float) -> float:
    """The frequency a step is analysed at: the stage's measured one, else the motor's, else the commanded."""
    f_use = sine.frequency_hz if np.isfinite(sine.frequency_hz) and sine.frequency_hz > 0 else motor_hz
    return float(f_use) if np.isfinite(f_use) and f_use > 0 else f_cmd


def window_contacts(
    t_mocap_s: np.ndarray,
    markers_m: dict[str, np.ndarray],
    t_force_s: np.ndarray,
    normal_n: np.ndarray,
    motor_velocity: np.ndarray,
    f_cmd: float,
    up_axis: str | None,
    stage_marker: str = "stage",
    foot_marker: str = "foot",
    params: ContactParams | None = None,
) -> ContactSummary:
    """The contacts of one record window (times in s from its start, markers in m, NaN where occluded) as the
    analysis finds them. The stage frame comes from this window's stage marker (the analysis takes it from the
    whole session's: the same axis up to the mocap noise). ``params``: the analysis's default contact rule."""
    stage = markers_m.get(stage_marker)
    frame = None
    if stage is not None and np.isfinite(stage).all(axis=1).sum() >= 3:
        try:
            frame = stage_frame(stage, up_axis, hanging_xyz=markers_m.get(foot_marker))
        except ValueError:
            frame = None
    f_use = analysis_frequency(stage_sine(t_mocap_s, stage, frame, f_cmd), motor_frequency(motor_velocity), f_cmd)
    return force_contacts(t_force_s, normal_n, f_use, params or ContactParams())[1]
