"""Offline analysis of beambench sessions: pure functions on arrays plus a per-session driver.

Notebook use::

    from beambench.sinks.session_file.reader import read_session
    from beambench.analysis import analyze_session, resample_session

    s = read_session("data/contact_sweep_sim_….h5")
    a = analyze_session(s)          # a.table: one row per step; a.fits: clock fits; a.steps: arrays
    df = resample_session(s, 1000)  # every stream on one host-clock timeline (raw data untouched)

Modules: ``signals`` (sine fit), ``trajectory`` (stage frame, ellipses, sense of travel), ``contact`` (touchdown velocity; the
events, ratios and regimes are :mod:`beambench.acquisition.forces.contact_events`), ``walking`` (body speed, foot stance), ``release`` (decay fit of a release test),
``session_analysis`` (per-step driver, ``/processing``), ``sync`` (device→host clock fits), ``figures`` (one module per report figure, registered by rig;
imports matplotlib), ``report`` (the figures of a session's rig and the HTML), ``synthetic`` (sessions with a
known truth for tests and demos).

The names below load on first use: importing one module of the package (the live view's step contacts, a run's
clock fit) does not load the per-session driver and with it pandas and SciPy (~0.4 s a process).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import (
        AnalysisOptions,
        SessionAnalysis,
        StepResult,
        analyze_session,
        contacts_table,
        resample_session,
        write_results,
    )
    from beambench.analysis.signals import SineFit, fit_sinusoid
    from beambench.analysis.trajectory import (
        Ellipse,
        StageFrame,
        fit_ellipse_harmonic,
        fit_ellipse_points,
        mean_path,
        relative_trajectory,
        stage_frame,
    )
    from beambench.analysis.walking import Speed, body_speed

_HOMES = {
    "AnalysisOptions": "session_analysis",
    "Ellipse": "trajectory",
    "SessionAnalysis": "session_analysis",
    "SineFit": "signals",
    "Speed": "walking",
    "StageFrame": "trajectory",
    "StepResult": "session_analysis",
    "analyze_session": "session_analysis",
    "body_speed": "walking",
    "contacts_table": "session_analysis",
    "fit_ellipse_harmonic": "trajectory",
    "fit_ellipse_points": "trajectory",
    "fit_sinusoid": "signals",
    "mean_path": "trajectory",
    "relative_trajectory": "trajectory",
    "resample_session": "session_analysis",
    "stage_frame": "trajectory",
    "write_results": "session_analysis",
}

__all__ = [
    "AnalysisOptions",
    "Ellipse",
    "SessionAnalysis",
    "SineFit",
    "Speed",
    "StageFrame",
    "StepResult",
    "analyze_session",
    "body_speed",
    "contacts_table",
    "fit_ellipse_harmonic",
    "fit_ellipse_points",
    "fit_sinusoid",
    "mean_path",
    "relative_trajectory",
    "resample_session",
    "stage_frame",
    "write_results",
]


def __getattr__(name: str) -> object:
    """A public name, from its module on first use (PEP 562)."""
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_HOMES])
