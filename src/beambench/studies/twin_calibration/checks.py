"""A calibration's targets as the verdict judges them (:mod:`.verdict`): one :class:`TargetCheck` per target —
its value, its tolerance and how to read the twin's value off a map. A rig builds them from its targets
(``CalibratableRig.checks``). Tolerances come from the targets file where it gives one (``tolerance_hz``,
``tolerance_fraction``), else the defaults here:

- a transition (contact rig: continuous edge, lowest ½, lowest ⅓): ± :data:`TRANSITION_TOLERANCE_HZ` Hz;
- a direction at contact (``tangential_sign`` at a frequency): the same sign; a session's per-step signs: at least
  :data:`SIGN_AGREEMENT` of them;
- a speed (walker): ± :data:`SPEED_TOLERANCE_FRACTION` of the target, at least that share of the objective's
  20 mm/s floor (a near-zero target is not judged to a fraction of nothing).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pandas as pd

TRANSITION_TOLERANCE_HZ = 2.0
SPEED_TOLERANCE_FRACTION = 0.30
SIGN_AGREEMENT = 0.9


@dataclass(frozen=True)
class TargetCheck:
    """One target: ``name`` (row of the report), ``kind`` (transition, sign, sign agreement, speed), the
    ``target`` value and ``tolerance`` in ``unit``, the tolerance as the report prints it (``tolerance_text``)
    and ``measure(steps)``: the twin's value on a map (None: the map does not have it)."""

    name: str
    kind: str
    target: float
    tolerance: float
    unit: str
    tolerance_text: str
    measure: Callable[[pd.DataFrame], float | None]

    def met(self, value: float | None) -> bool:
        return value is not None and math.isfinite(value) and abs(value - self.target) <= self.tolerance + 1e-9
