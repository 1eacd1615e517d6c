"""Model identification from a release test (paper Sec. II-B "Model fitting").

The paper released its beam from a 200 g tip load, recorded three tip markers returning to rest, and fitted
the PRB3 variables by differential evolution, minimising the RMS marker error over all samples::

    min sqrt( Σ_j Σ_i |M_i(j) − M̂_i(j)|² / (3n) )        (i: the three tip markers, j: the n samples)

The objective is a sum of squares over a time series, so by default it is minimised as one
(``method="sysid"``, :mod:`beambench.studies.fit.sysid`): MuJoCo's ``mujoco.sysid`` Levenberg–Marquardt, each
finite-difference Jacobian one batched rollout, started from the best of one batch screening the bounds (the
set's own values and a Latin hypercube), then ``mujoco.sysid.calculate_intervals`` gives each value's 95 %
interval. The paper's :func:`scipy.optimize.differential_evolution` stays (``method="de"``; ``"de+sysid"`` uses a
coarse DE as the global start for a bad initial guess): each generation's population is one batch of release
simulations (:func:`beambench.sim.scenes.release.release_batch`, one compiled model per member, stepped together
by ``mujoco.rollout`` on all cores), never one Python loop per member. Fitted variables (:class:`ParamSpace`),
each inside its physical bounds:

- **PRB3**: k, b (both on the bending and the twist joints, as in the paper), l2 with l1 = 0 and
  l3 = L − l2; with ``free_l1`` also l1 (l3 = L − l1 − l2). k and b are searched on a log scale.
- **Segmented rod** (``rodN``): Young's modulus E and the stiffness-proportional damping β (b = β·k), within the
  physical set's bounds (``sim_backend/rod_physical.yaml``, each with its source).

The release instant of measured data is known only to a sample or so (and the sim's mocap samples arrive
with a receive latency), so every candidate is compared at the best of a small grid of time shifts
(``shift_window_s``): a nuisance parameter minimised inside the objective at no extra simulation. The least
squares fits it as a bounded parameter instead (its interval is reported with the others).

:func:`load_release_session` turns a ``rig: release`` session into :class:`ReleaseData`; :func:`fit_release`
runs the fit; :func:`write_param_set` saves it as ``sim_backend/<model>_<name>.yaml`` (``sim.params: <name>``).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from beambench.acquisition.protocol.backends import BACKEND_INFO
from beambench.acquisition.protocol.scenes import runnable_names, scene_info, scene_or_unknown
from beambench.common.errors import BeambenchError
from beambench.common.names import check_name
from beambench.sim.engine.stepping import quiet_mujoco_warnings
from beambench.sim.models.params import SIM_BACKEND_DIR, BeamParams
from beambench.sim.models.registry import (
    UnknownModelError,
    canonical_model,
    default_params,
    is_rod,
    make_beam_model,
    model_family,
)
from beambench.sim.scenes.release import G, release_batch, release_models
from beambench.studies.fit.space import ParamSpace, ReleaseData
from beambench.studies.fit.sysid import CONFIDENCE, SHIFT, UNITS, ReleaseResidual, SysidFit

NS = 1_000_000_000
PAPER_MAE_MM = 3.49  # the paper's final error against its rig
RELEASE_SEARCH_SIM_S = 0.003  # sim sessions: the release is known on the sim clock; mocap adds latency + jitter
RELEASE_SEARCH_DETECTED_S = 0.006  # release found in the data: about a frame either way, and some margin


class FitError(BeambenchError, ValueError):
    """The input cannot be fitted (one-line message)."""


# ------------------------------------------------------------------------------------------------- data
def detect_release(t: np.ndarray, tip: np.ndarray, hold_fraction: float = 0.1) -> float:
    """Release time (s, on ``t``) from the tip markers' mean ``tip`` [n, M, 3]: the sample before the first that
    leaves the loaded hold (the first ``hold_fraction`` of the record) by more than 10 noise σ (≥ 1 mm)."""
    c = np.nanmean(tip, axis=1)
    n0 = max(5, int(len(t) * hold_fraction))
    hold = np.nanmedian(c[:n0], axis=0)
    dev = np.linalg.norm(c - hold, axis=1)
    sigma = 1.4826 * np.nanmedian(np.abs(np.diff(dev[:n0]))) / math.sqrt(2)
    moved = np.flatnonzero(dev > max(1e-3, 10 * sigma))
    if len(moved) == 0:
        raise FitError("no release found: the tip markers never leave their loaded position")
    k = max(int(moved[0]) - 1, 0)
    return float(t[k])


def register_to_model(
    data: ReleaseData, base: BeamParams | None = None, model: str = "prb3", rest_from_s: float = 0.15
) -> tuple[ReleaseData, np.ndarray, np.ndarray]:
    """Express measured markers in the model's frame (clamp at the origin, beam along +y, z up): the rigid
    transform (Kabsch) taking the measured rest pose (median after ``rest_from_s``) of the tip markers and the
    clamp (origin) onto the rest pose of the nominal model. Returns the data and (R, p) with x_model = R·x + p.
    For rigs whose mocap frame is not the model's (Motive's default is y-up); the nominal model's self-weight
    sag (~0.1 mm) is absorbed in the transform."""

    model = canonical_model(model)
    base = base or default_base(model)
    m = release_models([make_beam_model(model, base)], data.twist_deg, "implicitfast", 2e-4, len(data.names))
    ref = release_batch(m, data.load_g * 1e-3 * G, 0.0, data.names, nthread=1, with_rest=True).rest[0]
    late = data.t > rest_from_s
    if late.sum() < 3:
        raise FitError("too little data after the release to find the rest pose for --register")
    meas = np.nanmedian(data.markers[late], axis=0)
    a, b = meas, ref
    if data.clamp_relative:  # the clamp is the origin of both: a fourth point
        a, b = np.vstack([np.zeros(3), meas]), np.vstack([np.zeros(3), ref])
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    dfix = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rot = vt.T @ dfix @ u.T
    shift = cb - rot @ ca
    return replace(data, markers=data.markers @ rot.T + shift, clamp_relative=True), rot, shift


def load_release_session(
    path: str | Path, pre_s: float = 0.05, post_s: float = 0.35, register: bool | None = None
) -> ReleaseData:
    """Tip markers of a ``rig: release`` session, relative to the clamp (the stage marker's mean), on the host
    clock (device stamps through the session's clock fit), around the release: the scene's recorded release time
    on the sim, else detected from the data. ``register``: map the mocap frame onto the model's
    (:func:`register_to_model`); None = only for sessions not made by the sim (whose frame is the model's).
    Raises :class:`FitError` for sessions that are not release tests."""
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.analysis.session_analysis import fit_session_clocks, mocap_markers, stream_host_times
    from beambench.common.yaml_config import ConfigError
    from beambench.sinks.session_file.reader import SessionFileError, read_session

    try:
        s = read_session(path)
    except SessionFileError as exc:  # already one line naming the file
        raise FitError(str(exc)) from None
    except (OSError, KeyError) as exc:
        raise FitError(f"{path}: cannot read session ({exc})") from None
    try:
        proto = parse_protocol(str(s.general.get("protocol", "")), str(path))
    except ConfigError as exc:
        raise FitError(f"{path}: the session's protocol does not parse ({exc})") from None
    if not scene_or_unknown(proto.rig).free_decay:
        decays = " or ".join(n for n in runnable_names() if scene_info(n).free_decay)
        raise FitError(f"{path}: a {proto.rig} session; the fit needs a release test (rig: {decays})")
    mocap = s.streams.get("mocap")
    if mocap is None or len(mocap) < 20:
        raise FitError(f"{path}: no mocap data")
    labels, pos = mocap_markers(mocap)
    tips = tuple(n for n in labels if n.startswith("tip"))
    if not tips:
        raise FitError(f"{path}: no tip markers (tip1, tip2, tip3) in the mocap stream (has {labels})")
    fits = fit_session_clocks(s)
    t_ns = stream_host_times(mocap, fits.get("mocap"))
    order = np.argsort(t_ns, kind="stable")
    t_ns, pos = t_ns[order], pos[order]
    origin = np.nanmean(pos[:, labels.index("stage")], axis=0) if "stage" in labels else np.zeros(3)
    tip = pos[:, [labels.index(n) for n in tips]] - origin
    ident = s.general.get("identity", {})
    model = ident.get("model", {}) if isinstance(ident, dict) else {}
    rel_s = model.get("release_time_s") if isinstance(model, dict) else None
    t = (t_ns - t_ns[0]) / NS
    backend = BACKEND_INFO.get(str(ident.get("backend")))
    if rel_s is not None and backend is not None and backend.simulated_clock:
        t = t_ns / NS - float(rel_s)  # the clock is the simulated time since open(): the release is known exactly
        uncertainty = RELEASE_SEARCH_SIM_S
    else:
        t = t - detect_release(t, tip)
        uncertainty = RELEASE_SEARCH_DETECTED_S
    truth = {}
    if isinstance(model, dict) and "params" in model:
        truth = {"model": model.get("model"), **{k: model["params"].get(k) for k in ("k", "b", "l1", "l2", "l3")}}
        if "rod" in model:
            truth.update(youngs_modulus=model["rod"].get("youngs_modulus"), beta=model["rod"].get("beta"))
    params = model.get("params", {}) if isinstance(model, dict) else {}
    length = float(params.get("l1", 0) + params.get("l2", 0) + params.get("l3", 0)) if params else 0.050
    data = ReleaseData(
        t,
        tip,
        tips,
        twist_deg=proto.sim.twist_deg,
        load_g=proto.release.load_g,
        length=length or 0.050,
        source=str(path),
        release_uncertainty_s=uncertainty,
        clamp_relative="stage" in labels,
        truth=truth,
    ).window(pre_s, post_s)
    seen = int(np.isfinite(data.markers).all(axis=2).any(axis=1).sum()) if len(data.t) else 0
    if seen < 20:  # a clock that runs backwards or a release outside the data (an edited session)
        raise FitError(
            f"{path}: {seen} mocap frames with a tip marker within -{pre_s:g} … +{post_s:g} s of the release"
        )
    if register if register is not None else backend is None or not backend.model_frame:
        data = register_to_model(data)[0]
    return data


# -------------------------------------------------------------------------------------------- objective
class ReleaseObjective:
    """The paper's RMS marker error (m) of parameter vectors against ``data``, evaluated a population at a
    time: ``obj(X)`` with ``X`` [D, S] (scipy's ``vectorized`` layout) returns [S]. Each call compiles one
    model per member and releases them all in one ``mujoco.rollout`` batch on ``nthread`` threads."""

    def __init__(
        self,
        data: ReleaseData,
        space: ParamSpace,
        timestep: float = 2e-4,
        integrator: str = "implicitfast",
        nthread: int | None = None,
        shift_window_s: float = 0.0,
        shift_step_s: float = 1e-4,
    ) -> None:
        from mujoco import rollout

        self.data, self.space = data, space
        self.timestep, self.integrator, self.nthread = timestep, integrator, nthread
        self.shift_window = shift_window_s
        self.shift_step = shift_step_s
        self.duration = float(np.nanmax(data.t)) + shift_window_s + 2 * timestep
        self.valid = np.isfinite(data.markers).all(axis=2)  # [n, M]
        self.count = max(1, int(self.valid.sum()))
        self.meas = np.where(self.valid[..., None], data.markers, 0.0)
        self.nfev = 0
        self.diverged = 0
        self.batches = 0
        self.sim_wall = 0.0
        threads = nthread or os.cpu_count() or 1
        self._roller = rollout.Rollout(nthread=threads if threads > 1 else 0)

    def close(self) -> None:
        self._roller.close()

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, float))
        if X.shape[0] != len(self.space.variables):
            X = X.T
        err, _, _ = self.evaluate(X.T)
        return err

    def evaluate(self, xs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """RMS error (m) [S], best shift (s) [S] and the predicted markers at the data times [S, n, M, 3]."""

        xs = np.atleast_2d(xs)
        S = len(xs)
        beams = [make_beam_model(self.space.model, self.space.params(x)) for x in xs]
        models = release_models(beams, self.data.twist_deg, self.integrator, self.timestep, len(self.data.names))
        t0 = time.perf_counter()
        rb = release_batch(
            models, self.data.load_g * 1e-3 * G, self.duration, self.data.names, self.nthread, roller=self._roller
        )
        self.sim_wall += time.perf_counter() - t0
        self.nfev += S
        self.batches += 1
        # the release instant as a nuisance parameter: coarse grid over the window, then fine around the best
        shifts = np.zeros((S, 1))
        if self.shift_window > 0:
            coarse = 5 * self.shift_step
            k = math.ceil(self.shift_window / coarse - 1e-9)
            grid = np.tile(np.arange(-k, k + 1) * coarse, (S, 1))
            best = grid[np.arange(S), np.argmin(self._rms(rb, grid), axis=1)]
            shifts = best[:, None] + np.arange(-5, 6) * self.shift_step
        rms = self._rms(rb, shifts)
        j = np.argmin(rms, axis=1)
        err = rms[np.arange(S), j]
        shift = shifts[np.arange(S), j]
        bad = ~rb.ok | ~np.isfinite(err)
        err[bad] = 1.0
        self.diverged += int(bad.sum())
        return err, shift, self._at_times(rb, shift[:, None])[:, 0]

    def _rms(self, rb: Any, shifts: np.ndarray) -> np.ndarray:
        """RMS marker distance [S, K] of each member at each of its shifts ``shifts`` [S, K]."""
        out = np.empty(shifts.shape)
        for k in range(shifts.shape[1]):
            pred = self._at_times(rb, shifts[:, k : k + 1])[:, 0]  # [S, n, M, 3]
            d2 = np.sum((pred - self.meas) ** 2, axis=-1) * self.valid
            out[:, k] = np.sqrt(d2.sum(axis=(1, 2)) / self.count)
        return out

    def _at_times(self, rb: Any, shifts: np.ndarray) -> np.ndarray:
        """Simulated markers at ``data.t − shift`` for each member's shifts [S, K]: [S, K, n, M, 3] (the
        loaded hold before the release, linear interpolation between steps after it)."""
        h = rb.t[1] - rb.t[0]
        tau = self.data.t[None, None, :] - shifts[:, :, None]  # [S, K, n]
        pos = np.clip(tau / h, 0.0, len(rb.t) - 1.000001)
        i = pos.astype(int)
        w = (pos - i)[..., None, None]
        s = np.arange(len(shifts))[:, None, None]
        out = rb.markers[s, i] * (1 - w) + rb.markers[s, i + 1] * w
        return np.where((tau < 0)[..., None, None], rb.loaded[:, None, None], out)


# ------------------------------------------------------------------------------------------------- fit
@dataclass
class FitResult:
    """A finished fit: the values, the final error and what it cost."""

    model: str
    values: dict[str, float]
    params: BeamParams
    rms_mm: float
    mae_mm: float  # mean marker distance (the paper's "mean absolute error")
    max_mm: float
    shift_s: float
    nfev: int
    generations: int
    wall_s: float
    sim_wall_s: float
    converged: bool
    message: str
    t: np.ndarray
    measured: np.ndarray
    fitted: np.ndarray
    names: tuple[str, ...]
    history: list[float] = field(default_factory=list)
    truth: dict[str, Any] = field(default_factory=dict)
    integrator: str = ""
    timestep: float = 0.0
    diverged: int = 0  # candidates whose simulation blew up (scored as 1 m)
    mujoco_warnings: int = 0
    method: str = "de"
    # CONFIDENCE intervals (SI) of the fitted values by name, ``release_shift`` (s) too where it was fitted
    intervals: dict[str, tuple[float, float]] = field(default_factory=dict)
    confidence: float = CONFIDENCE
    # searched variables that ended within AT_BOUND of a bound (on their search axis): the data asks for a value
    # the physical box does not allow, and their interval is not a confidence interval (a constrained optimum)
    at_bounds: dict[str, str] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        return {
            "model": self.model,
            "method": self.method,
            "values": self.values,
            "intervals": {k: list(v) for k, v in self.intervals.items()},
            "confidence": self.confidence,
            "rollouts": self.nfev,
            "at_bounds": self.at_bounds,
            "rms_mm": self.rms_mm,
            "mae_mm": self.mae_mm,
            "max_mm": self.max_mm,
            "shift_ms": self.shift_s * 1e3,
            "nfev": self.nfev,
            "generations": self.generations,
            "wall_s": self.wall_s,
            "sim_wall_s": self.sim_wall_s,
            "converged": self.converged,
            "message": self.message,
            "integrator": self.integrator,
            "timestep": self.timestep,
            "diverged_candidates": self.diverged,
            "paper_mae_mm": PAPER_MAE_MM,
            "truth": self.truth,
        }


def default_base(model: str) -> BeamParams:
    """The parameter set a fit starts from (geometry, mass, material): the paper's."""
    return default_params(model)


def default_integrator(model: str) -> str:
    """implicitfast, the scenes' own, for every family. Over the rods' physical box (E 12–30 MPa, β ≥ 0.4 ms) it
    is stable at dt = 2e-4 and 0.02–0.36 mm RMS from a dt = 2.5e-5 reference, where ``discrete`` (used while the
    box reached 120 MPa and β = 0.01 ms, where implicitfast diverged) is 0.03–3.6 mm off: its numerical damping
    made a least-squares fit read β 13 % low."""
    del model
    return "implicitfast"


METHODS = ("sysid", "de", "de+sysid")
AT_BOUND = 0.01  # a fitted value this close to a bound (share of its search range) is reported as at it
COARSE_DE_TOL = 0.05  # de+sysid: the DE only finds the basin (errors' spread 5 % of their mean), sysid refines


@dataclass(frozen=True)
class FitOptions:
    """How a release fit runs: ``method`` — ``sysid`` (a one-batch screen of the box for the start, then
    ``mujoco.sysid`` least squares; :mod:`beambench.studies.fit.sysid`), ``de`` (differential evolution, the
    paper's optimizer) or ``de+sysid`` (a coarse DE, stopped at a 5 % spread of its population's errors, as the
    global start; sysid refining); ``free_l1`` (PRB3: fit l1 too); the differential evolution's ``popsize``,
    ``maxiter``, ``tol`` and ``seed``; the least squares' ``max_iters`` and the screen's size (``screen`` × the
    number of variables, plus the set's own values); the simulation's ``timestep``, ``integrator`` (None: the
    model's default) and threads (``nthread``, None: all cores), and the release-time search window (None: the
    data's own uncertainty)."""

    method: str = "sysid"
    free_l1: bool = False
    popsize: int = 12
    maxiter: int = 60
    tol: float = 1e-3
    seed: int = 0
    timestep: float = 2e-4
    integrator: str | None = None
    nthread: int | None = None
    shift_window_s: float | None = None
    max_iters: int = 40
    screen: int = 4


def fit_release(
    data: ReleaseData,
    model: str = "prb3",
    options: FitOptions = FitOptions(),
    base: BeamParams | None = None,
    progress: Callable[[int, float], None] | None = None,
) -> FitResult:
    """Fit ``model`` (``prb3`` or a rod ``rodN``; ``rod`` means ``rod10``) to a release test by ``options.method``
    (see :class:`FitOptions`); every step evaluates its candidates in one batched simulation. ``progress`` is
    called with (generation or iteration, best RMS in m). The result carries each value's interval from
    ``mujoco.sysid.calculate_intervals`` at the optimum (for ``de`` too: one Jacobian there)."""
    if options.method not in METHODS:
        raise FitError(f"--method = {options.method!r}: one of {', '.join(METHODS)}")
    try:
        model = canonical_model(model)
    except UnknownModelError:
        raise FitError(f"--model = {model!r}: prb3 or rod (rod10, rod5, rod3g …)") from None
    rod = is_rod(model)
    if rod and options.free_l1:
        raise FitError("--free-l1 applies to prb3 only")
    base = base or default_base(model)
    if abs(base.length - data.length) > 1e-6:
        base = replace(base, l2=data.length / 2, l3=data.length / 2) if rod else base
    space = ParamSpace.rod(base, model) if rod else ParamSpace.prb3(base, options.free_l1)
    window = data.release_uncertainty_s if options.shift_window_s is None else options.shift_window_s
    integrator = options.integrator or default_integrator(model)
    obj = ReleaseObjective(data, space, options.timestep, integrator, options.nthread, window)
    history: list[float] = []
    t0 = time.perf_counter()

    def step(k: int, best: float) -> None:
        history.append(best)
        if progress is not None:
            progress(len(history), best)

    try:
        with quiet_mujoco_warnings() as warned:
            if options.method == "sysid":
                x, message, converged = _screen(obj, space, options.screen * len(space.variables), options.seed)
            else:
                x, message, converged = _differential_evolution(obj, space, options, step)
            _, shift, _ = obj.evaluate(np.asarray(x)[None])
            threads = options.nthread or os.cpu_count() or 1
            try:
                lsq = ReleaseResidual(data, space, options.timestep, integrator, threads, window)
            except ValueError as exc:
                raise FitError(f"{data.source or 'release data'}: {exc}") from None
            if options.method == "de":  # the intervals at the DE optimum: one Jacobian, no refinement
                sysid_fit = lsq.fit(x, float(shift[0]), max_iters=0)
            else:
                sysid_fit = lsq.fit(x, float(shift[0]), options.max_iters, progress=step)
                message = f"{message}; {sysid_fit.status}"
                converged = sysid_fit.converged
    finally:
        obj.close()
    wall = time.perf_counter() - t0
    x, shift_s, pred = sysid_fit.x, sysid_fit.shift_s, sysid_fit.fitted
    dist = np.linalg.norm(pred - data.markers, axis=-1)[obj.valid]
    intervals = _physical_intervals(space, sysid_fit)
    return FitResult(
        model,
        space.values(x),
        space.params(x),
        sysid_fit.rms_mm,
        float(np.mean(dist)) * 1e3,
        float(np.max(dist)) * 1e3,
        shift_s,
        obj.nfev + sysid_fit.rollouts,
        len(history),
        wall,
        obj.sim_wall + sysid_fit.sim_wall_s,
        converged,
        message,
        data.t,
        data.markers,
        pred,
        data.names,
        history,
        data.truth,
        integrator,
        options.timestep,
        obj.diverged,
        len(warned),
        options.method,
        intervals,
        CONFIDENCE,
        _at_bounds(space, x),
    )


def _at_bounds(space: ParamSpace, x: Sequence[float] | np.ndarray) -> dict[str, str]:
    """The variables at (within :data:`AT_BOUND` of) a bound: name → "lower/upper bound <value>"."""
    out = {}
    for var, xi in zip(space.variables, x):
        lo, hi = var.bounds
        if xi - lo <= AT_BOUND * (hi - lo):
            out[var.name] = f"lower bound {var.lo:g} {var.unit}".strip()
        elif hi - xi <= AT_BOUND * (hi - lo):
            out[var.name] = f"upper bound {var.hi:g} {var.unit}".strip()
    return out


def _screen(obj: ReleaseObjective, space: ParamSpace, n: int, seed: int) -> tuple[np.ndarray, str, bool]:
    """The least squares' start: the best of the set's own values and ``n`` Latin-hypercube points over the
    bounds, evaluated in one batch (the release shift profiled as in DE)."""
    from scipy.stats import qmc

    lo, hi = np.array(space.bounds()).T
    own = np.clip([v.coord(_own_value(space, v.name)) for v in space.variables], lo, hi)
    pts = qmc.scale(qmc.LatinHypercube(d=len(lo), seed=seed).random(n), lo, hi) if n > 0 else np.empty((0, len(lo)))
    xs = np.vstack([own, pts])
    err, _, _ = obj.evaluate(xs)
    best = int(np.argmin(err))
    where = "the set's own values" if best == 0 else f"screen point {best} of {n}"
    return xs[best], f"start: {where} ({err[best] * 1e3:.3f} mm, {len(xs)} screened)", True


def _own_value(space: ParamSpace, name: str) -> float:
    """The base set's own value of a search variable (``l2_share``: l2 of what l1 leaves)."""
    p = space.base
    own = {
        "k": p.k,
        "b": p.b,
        "l1": max(p.l1, 0.001),
        "l2": p.l2,
        "l2_share": p.l2 / max(p.length - max(p.l1, 0.001), 1e-9),
        "youngs_modulus": p.material.youngs_modulus,
        "beta": p.beta,
    }
    return float(own[name])


def _differential_evolution(
    obj: ReleaseObjective, space: ParamSpace, options: FitOptions, step: Callable[[int, float], None]
) -> tuple[np.ndarray, str, bool]:
    """The paper's optimizer, each generation one batch (``vectorized``)."""
    from scipy.optimize import differential_evolution

    def callback(intermediate_result: Any) -> None:  # scipy passes the best so far by this parameter's name
        step(0, float(intermediate_result.fun))

    res = differential_evolution(
        obj,
        space.bounds(),
        popsize=options.popsize,
        maxiter=options.maxiter,
        tol=options.tol if options.method == "de" else max(options.tol, COARSE_DE_TOL),
        rng=np.random.default_rng(options.seed),
        vectorized=True,
        updating="deferred",
        polish=False,
        init="latinhypercube",
        mutation=(0.5, 1.0),
        recombination=0.7,
        callback=callback,
    )
    return res.x, str(res.message), bool(res.success)


def _physical_intervals(space: ParamSpace, fit: SysidFit) -> dict[str, tuple[float, float]]:
    """The sysid intervals by the names :meth:`ParamSpace.values` reports (``l2_share`` → l2 at the fitted l1;
    l1's own uncertainty is not carried into it)."""
    out = dict(fit.intervals)
    if "l2_share" in out:
        rest = space.base.length - space.values(fit.x)["l1"]
        lo, hi = out.pop("l2_share")
        out["l2"] = (lo * rest, hi * rest)
    if SHIFT in out:
        out["release_shift_s"] = out.pop(SHIFT)
    return out


# ------------------------------------------------------------------------------------------------ output
def value_with_interval(result: FitResult, key: str) -> str:
    """``key``'s fitted value ± the half-width of its interval, in the report's unit (``20.01 ± 0.027 MPa``); an
    asymmetric interval (l2 derived from its share) as ``[lo, hi]``."""
    shift = key == "release_shift_s"
    value = result.shift_s if shift else result.values[key]
    scale, unit = UNITS.get(SHIFT if shift else key, (1.0, ""))
    v, text = value * scale, f"{value * scale:.5g}"
    if key in result.intervals:
        lo, hi = (x * scale for x in result.intervals[key])
        symmetric = math.isclose(hi - v, v - lo, rel_tol=1e-3, abs_tol=1e-12)
        text += f" ± {(hi - lo) / 2:.2g}" if symmetric else f" [{lo:.5g}, {hi:.5g}]"
    return f"{text} {unit}".strip()


def interval_summary(result: FitResult) -> str:
    """One line: every fitted value ± its interval, the confidence level and where it comes from."""
    keys = [k for k in result.intervals if k in result.values or k == "release_shift_s"]
    parts = [f"{k} = {value_with_interval(result, k)}" for k in keys]
    text = f"{', '.join(parts)} ({result.confidence:.0%} confidence, mujoco.sysid.calculate_intervals)"
    if result.at_bounds:
        text += "; at its bound, no confidence interval: " + ", ".join(
            f"{k} ({w})" for k, w in result.at_bounds.items()
        )
    return text


def param_set_dict(result: FitResult, name: str, source: str) -> dict[str, Any]:
    """The YAML document of a fitted parameter set (same layout as ``sim_backend/prb3_paper.yaml``)."""
    p = result.params
    beam: dict[str, Any]
    if not is_rod(result.model):
        beam = {"l1": p.l1, "l2": p.l2, "l3": p.l3, "k": p.k, "b": p.b, "k_twist": p.k_twist, "b_twist": p.b_twist}
    else:
        beam = {"l1": p.l1, "l2": p.l2, "l3": p.l3, "beta": p.beta}
    beam.update(
        mass=p.mass,
        width=p.width,
        thickness=p.thickness,
        twist_deg=p.twist_deg,
        material={
            "youngs_modulus": p.material.youngs_modulus,
            "poisson": p.material.poisson,
            "density": p.material.density,
        },
    )
    return {
        "name": name,
        "model": model_family(result.model),
        "source": source,
        "beam": {
            k: (float(v) if not isinstance(v, dict) else {kk: float(vv) for kk, vv in v.items()})
            for k, v in beam.items()
        },
        "fit": {
            "model": result.model,
            "rms_mm": round(result.rms_mm, 4),
            "mae_mm": round(result.mae_mm, 4),
            "nfev": result.nfev,
            "wall_s": round(result.wall_s, 2),
            "date": datetime.now().isoformat(timespec="seconds"),
            "method": result.method,
            "confidence": result.confidence,
            "intervals": {k: [float(lo), float(hi)] for k, (lo, hi) in result.intervals.items()},  # SI
            "notes": interval_summary(result),
        },
    }


def write_param_set(result: FitResult, name: str, directory: str | Path = SIM_BACKEND_DIR, source: str = "") -> Path:
    """Save the fit as ``<directory>/<family>_<name>.yaml``; it loads back with ``load_params(name)``."""
    family = model_family(result.model)
    check_name(name, "the parameter set name")  # one path component: never written outside ``directory``
    path = Path(directory) / f"{family}_{name}.yaml"
    source = source or f"beambench fit ({result.model})"
    doc = param_set_dict(result, name, f"{source}: RMS {result.rms_mm:.3f} mm; {interval_summary(result)}")
    header = (
        f"# Fitted by `beambench fit` to a release test ({result.model}, {result.method}; RMS {result.rms_mm:.3f} mm, "
        f"mean marker error {result.mae_mm:.3f} mm). SI units; intervals under fit:.\n"
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(header + yaml.safe_dump(doc, sort_keys=False, allow_unicode=True))
    return path


# ----------------------------------------------------------------------------------------- synthetic data
@dataclass(frozen=True)
class ReleaseTest:
    """A synthetic release test's setup: twist, tip load, mocap rate, the window around the release and the
    simulation's timestep."""

    twist_deg: float = 90.0
    load_g: float = 200.0
    rate_hz: float = 360.0
    pre_s: float = 0.05
    post_s: float = 0.35
    timestep: float = 1e-4


def synthetic_release(
    params: BeamParams, model: str = "prb3", noise_m: float = 3e-4, seed: int = 0, test: ReleaseTest = ReleaseTest()
) -> ReleaseData:
    """A release test made by the sim from known parameters: the tip markers sampled at ``test.rate_hz`` with a
    random phase to the release, plus Gaussian noise ``noise_m`` per coordinate (``seed``)."""
    twist_deg, load_g, rate_hz, pre_s, post_s = test.twist_deg, test.load_g, test.rate_hz, test.pre_s, test.post_s
    timestep = test.timestep
    rng = np.random.default_rng(seed)
    m = release_models([make_beam_model(model, params)], twist_deg, "implicitfast", timestep)
    rb = release_batch(m, load_g * 1e-3 * G, post_s + 0.01, nthread=1)
    phase = rng.uniform(0, 1 / rate_hz)
    t = np.arange(-pre_s + phase, post_s, 1 / rate_hz)
    clean = np.empty((len(t), len(rb.names), 3))
    for j in range(len(rb.names)):
        for c in range(3):
            clean[:, j, c] = np.interp(t, rb.t, rb.markers[0, :, j, c])
    clean[t < 0] = rb.loaded[0]
    noisy = clean + rng.normal(0.0, noise_m, clean.shape)
    truth = {
        "model": model,
        "k": params.k,
        "b": params.b,
        "l1": params.l1,
        "l2": params.l2,
        "l3": params.l3,
        "youngs_modulus": params.material.youngs_modulus,
        "beta": params.beta,
        "noise_m": noise_m,
    }
    return ReleaseData(t, noisy, rb.names, twist_deg, load_g, params.length, source="synthetic", truth=truth)
