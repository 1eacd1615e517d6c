"""Whether a calibration reached its targets: one :class:`Verdict` per target (met within its tolerance or not)
and, for a miss, the unknown that limits it.

A rig names its targets as :class:`~.checks.TargetCheck` s (``CalibratableRig.checks(targets)``; the
tolerances: :mod:`.checks`).

The winner's map is also run at a few more noise seeds (``SearchSettings.spread_seeds``): a missed target that
one of them meets is limited by the twin's own seed-to-seed spread (irregular regimes that change with the noise
seed: no unknown is to blame), and every verdict carries that spread. Otherwise a missed target is *limited by*
a free unknown that sits at (within :data:`AT_BOUND_FRACTION` of its search span,
on its log axis where it has one) one of its bounds at the best point, preferring one that the evaluated points
say moves the twin's value toward the target when pushed past that bound (a weighted local linear fit of the
value over the points, as the landmark steps fit theirs); with none at a bound, no unknown moves it far enough.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from beambench.studies.twin_calibration.checks import TargetCheck
from beambench.studies.twin_calibration.landmark_steps import fit_local_linear

if TYPE_CHECKING:
    from beambench.studies.twin_calibration.evaluate import Point
    from beambench.studies.unknowns import Unknown

AT_BOUND_FRACTION = 0.03
NOT_FAR_ENOUGH = "no unknown moves it far enough"


@dataclass(frozen=True)
class Verdict:
    """A target against the calibrated twin: ``twin`` is None where its map lacks the quantity; ``limited_by``
    (misses only) names the unknown at a bound or says :data:`NOT_FAR_ENOUGH`."""

    target: str
    kind: str
    wanted: float
    twin: float | None
    tolerance: float
    tolerance_text: str
    unit: str
    met: bool
    limited_by: str | None = None
    seed_spread: tuple[float, float] | None = None  # the value's range over the noise seeds the winner ran at
    seeds: int = 1

    def spread_text(self) -> str:
        """``33.0 … 40.0 Hz (4 seeds)``, or empty without a spread."""
        if self.seed_spread is None:
            return ""
        lo, hi = self.seed_spread
        return f"{lo:.4g} … {hi:.4g}{_u(self.unit)} ({self.seeds} seeds)"

    def wanted_text(self) -> str:
        return f"{self.wanted:.4g}{_u(self.unit)}"

    def twin_text(self) -> str:
        return "none" if self.twin is None else f"{self.twin:.4g}{_u(self.unit)}"

    def line(self) -> str:
        """``half_at_hz: twin 17 Hz, target 26 ± 2 Hz — met`` (a miss: ``— missed, <limited_by>``)."""
        head = f"{self.target}: twin {self.twin_text()}, target {self.wanted_text()} {self.tolerance_text}"
        return f"{head} — met" if self.met else f"{head} — missed, {self.limited_by or NOT_FAR_ENOUGH}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "target": self.target,
            "kind": self.kind,
            "wanted": self.wanted,
            "twin": self.twin,
            "tolerance": self.tolerance,
            "tolerance_text": self.tolerance_text,
            "unit": self.unit,
            "met": self.met,
            "limited_by": self.limited_by,
            "seed_spread": list(self.seed_spread) if self.seed_spread is not None else None,
            "seeds": self.seeds,
        }


def _u(unit: str) -> str:
    return f" {unit}" if unit else ""


def judge(
    checks: Sequence[TargetCheck],
    winner: Point,
    points: Sequence[Point],
    free: Sequence[Unknown],
    seeds: Sequence[Point] = (),
    held: Sequence[Unknown] = (),
) -> list[Verdict]:
    """Every check on the winner's map; a miss names its limit: the twin's own spread over the noise ``seeds``
    (the winner's map at other seeds) when one of them meets it, else from the winner's values, the ``points``
    evaluated and the ``free`` unknowns' bounds (naming the rig's ``held`` unknowns, not searched, when no free
    one is at a bound)."""
    out = []
    steps, best = winner.steps, winner.values
    for c in checks:
        v = _finite(c.measure(steps))
        ok = c.met(v)
        across = [x for x in (_finite(c.measure(p.steps)) for p in seeds) if x is not None]
        spread = (min(across), max(across)) if len(seeds) > 1 and across else None
        why = None
        if not ok:
            met_by = [x for x in across if c.met(x)]
            why = (
                seed_spread_text(spread, len(seeds), len(met_by), c.unit)
                if met_by and spread is not None
                else limiting_unknown(c, v, best, points, free, held)
            )
        tol, unit = c.tolerance_text, c.unit
        out.append(Verdict(c.name, c.kind, c.target, v, c.tolerance, tol, unit, ok, why, spread, max(1, len(seeds))))
    return out


def seed_spread_text(spread: tuple[float, float], seeds: int, meeting: int, unit: str) -> str:
    """A miss that other noise seeds meet: the twin's own spread, not a bound."""
    lo, hi = spread
    return (
        f"the twin's own seed-to-seed spread covers it ({lo:.4g} … {hi:.4g}{_u(unit)} over {seeds} noise seeds, "
        f"{meeting} within tolerance: irregular regimes that change with the noise seed), not a bound"
    )


def _finite(v: float | None) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None


def at_bound(values: dict[str, float], free: Sequence[Unknown]) -> list[tuple[Unknown, int]]:
    """The free unknowns within :data:`AT_BOUND_FRACTION` of a bound at ``values`` (on the search axis), each
    with the side: −1 at its lower bound, +1 at its upper."""
    out = []
    for u in free:
        if u.name not in values:
            continue
        lo, hi = u.bounds
        x = (u.coord(values[u.name]) - lo) / (hi - lo)
        if x <= AT_BOUND_FRACTION:
            out.append((u, -1))
        elif x >= 1.0 - AT_BOUND_FRACTION:
            out.append((u, 1))
    return out


def limiting_unknown(
    check: TargetCheck,
    value: float | None,
    best: dict[str, float],
    points: Sequence[Point],
    free: Sequence[Unknown],
    held: Sequence[Unknown] = (),
) -> str:
    """What keeps ``check`` from its target (module docstring): ``preload_mm at its upper bound 1 mm``, or
    :data:`NOT_FAR_ENOUGH` (with the reason where one unknown is at a bound but moves it the wrong way, or the
    ``held`` unknowns the search did not move, which ``--free`` would)."""
    edge = at_bound(best, free)
    if not edge:
        why = [f"none of {', '.join(u.name for u in free)} is at a bound"] if free else []
        if held:
            why.append(f"not searched: {', '.join(u.name for u in held)} (--free)")
        return f"{NOT_FAR_ENOUGH} ({'; '.join(why)})" if why else NOT_FAR_ENOUGH
    slopes = _slopes(check, best, points, free)
    if slopes is not None and value is not None:
        want = check.target - value
        helps = [(u, side) for u, side in edge if side * slopes[u.name] * want > 0]
        if not helps:
            names = " or ".join(f"{u.name} past its {_side(side)} bound" for u, side in edge)
            return f"{NOT_FAR_ENOUGH} ({names} would move it the wrong way)"
        edge = sorted(helps, key=lambda e: -abs(slopes[e[0].name]))
    return "; ".join(
        f"{u.name} at its {_side(side)} bound {u.hi if side > 0 else u.lo:g}{_u(u.unit)}" for u, side in edge[:1]
    ) + (f" (also at a bound: {', '.join(u.name for u, _ in edge[1:])})" if len(edge) > 1 else "")


def _side(side: int) -> str:
    return "upper" if side > 0 else "lower"


def _slopes(
    check: TargetCheck, best: dict[str, float], points: Sequence[Point], free: Sequence[Unknown]
) -> dict[str, float] | None:
    """d(twin value)/d(unit coordinate) of each free unknown at ``best`` from the evaluated points (None when
    the points do not pin a plane)."""
    if not free or len(points) < len(free) + 3:
        return None
    lo = np.array([u.bounds[0] for u in free])
    span = np.array([u.bounds[1] - u.bounds[0] for u in free])

    def unit(values: dict[str, float]) -> np.ndarray:
        return (np.array([u.coord(values[u.name]) for u in free]) - lo) / span

    x = np.array([unit(p.values) for p in points])
    y = np.array([[_nan(check.measure(p.steps))] for p in points])
    model = fit_local_linear(x, y, unit(best), scale=0.3)
    if not model.fitted[0]:
        return None
    return {u.name: float(model.jacobian[0, i]) for i, u in enumerate(free)}


def _nan(v: float | None) -> float:
    return math.nan if v is None else float(v)


def all_met(verdicts: Sequence[Verdict]) -> bool:
    return all(v.met for v in verdicts)


def closing_line(verdicts: Sequence[Verdict], shown: int = 3) -> str:
    """The command's last line: every target met, or the misses (the first ``shown``) with their limits."""
    missed = [v for v in verdicts if not v.met]
    if not verdicts:
        return "no target this rig's verdict can judge"
    if not missed:
        return f"every target met within tolerance ({len(verdicts)} of {len(verdicts)})"
    more = f"; and {len(missed) - shown} more" if len(missed) > shown else ""
    return (
        f"not within tolerance: {len(missed)} of {len(verdicts)} targets missed: "
        + "; ".join(
            f"{v.target} twin {v.twin_text()} vs {v.wanted_text()} {v.tolerance_text}, {v.limited_by or NOT_FAR_ENOUGH}"
            for v in missed[:shown]
        )
        + more
    )


def annotate_yaml(path: Path, verdicts: Sequence[Verdict]) -> None:
    """Add the verdict as comment lines after ``path``'s leading comments (a YAML file the calibration wrote)."""
    if not path.is_file() or not verdicts:
        return
    lines = path.read_text().splitlines(keepends=True)
    n = next((i for i, line in enumerate(lines) if not line.startswith("#")), len(lines))
    note = [f"# verdict: {closing_line(verdicts)}\n"] + [f"#   {v.line()}\n" for v in verdicts]
    path.write_text("".join(lines[:n] + note + lines[n:]))
