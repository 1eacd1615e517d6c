"""``beambench calibrate sim``: fit a rig's twin to measured per-step results or to published numbers.

- :mod:`.rig`: what the calibrator knows of a rig (:class:`CalibratableRig`: its :class:`Unknown` s with their
  bounds, ``simulate``, ``objective``, how its values go into a protocol), the fixed part of its twin
  (:class:`CalibrationBase`) and the registry;
- :mod:`.contact`, :mod:`.walker`: one module per calibratable rig, each registering itself at import (this
  package imports them, so every rig is known wherever the package is);
- :mod:`.search`: the search (lines, landmark steps, evolution, refine, verify), the same for every rig;
  :mod:`.evaluate`: the evaluation log, the evaluator, the settings; :mod:`.landmark_steps`;
- :mod:`.checks`, :mod:`.verdict`: each target with its tolerance, and after the search whether the twin met it
  and what limits a miss (the command exits 5 then); :mod:`.intervals`: the unknowns' intervals;
- :mod:`.report`, :mod:`.protocol_out`: what a calibration writes; :mod:`.targets`: what it fits to;
  :mod:`.written_run`: running a written protocol as its user will.

Plugging in a rig: a module whose ``@register_rig`` function returns its ``CalibratableRig(name=..., unknowns=(...),
simulate=..., objective=..., base=..., write=..., summary=..., checks=..., file_targets=..., session_targets=...)``,
imported below (``--targets`` and ``--session`` go to the readers of the rig they name); ``simulate`` returns
``{"steps": [{"frequency_hz": f, ...}, ...], "extras": {...}}`` and the objective compares them with
``targets.table``. The CLI, the search, the log and the report are rig-agnostic.
"""

from beambench.studies.twin_calibration import contact, walker
from beambench.studies.twin_calibration.evaluate import (
    EvalLog,
    Evaluator,
    Interrupted,
    Point,
    SearchSettings,
    quick_help,
)
from beambench.studies.twin_calibration.report import write_report
from beambench.studies.twin_calibration.rig import (
    RIGS,
    CalibratableRig,
    CalibrationBase,
    get_rig,
    register_rig,
    unknowns_help,
)
from beambench.studies.twin_calibration.search import Result, calibrate

__all__ = [
    "RIGS",
    "CalibratableRig",
    "CalibrationBase",
    "EvalLog",
    "Evaluator",
    "Interrupted",
    "Point",
    "Result",
    "SearchSettings",
    "calibrate",
    "contact",
    "get_rig",
    "quick_help",
    "register_rig",
    "unknowns_help",
    "walker",
    "write_report",
]
