"""The release fit's least-squares refinement and confidence intervals, by MuJoCo's own ``mujoco.sysid``.

The paper's objective, the RMS tip-marker error, is a sum of squares over a time series, so it is minimised here
as one: :func:`mujoco.sysid.optimize` (MuJoCo's bounded Levenberg–Marquardt, ``mujoco.minimize``) on the residual
vector of every valid marker coordinate at every sample (mm), each finite-difference Jacobian one batched
``mujoco.rollout`` of all its columns; then :func:`mujoco.sysid.calculate_intervals` turns the Jacobian and the
residual at the optimum into a confidence interval for each parameter (Student-t, :data:`CONFIDENCE`).

How the release test plugs into the sysid pipeline (:func:`mujoco.sysid.build_residual_fn`):

- **Parameters** — one :class:`mujoco.sysid.Parameter` per searched :class:`~beambench.studies.unknowns.Unknown`,
  with the unknown's physical bounds, in the units the report uses (MPa, ms, mm, …: well scaled for the
  optimizer's finite differences), plus the release instant's offset ``release_shift`` (ms) within the data's
  uncertainty — the nuisance the differential evolution profiles out on a grid is here a fitted parameter, so
  its correlation with the physics is in the intervals. Without an uncertainty (synthetic data) it is frozen.
- **build_model** — the project's builder (:func:`beambench.sim.scenes.release.build_release_spec` from the
  :class:`~beambench.sim.models.params.BeamParams` of the values), not a spec field per parameter: one stiffness
  acts on several joints.
- **custom_rollout** — each candidate starts from its *own* loaded static equilibrium (the state sysid would
  otherwise take from the data), then :func:`mujoco.sysid.sysid_rollout` steps the batch with the load let go.
- **modify_residual** — the simulated markers at the data's times minus the release shift (the loaded hold
  before it), minus the measured ones (already registered to the model's frame), NaN samples left out. A sensor
  row of ``mujoco.rollout`` is evaluated before its step, so its time is the state row's minus one timestep.
"""

from __future__ import annotations

import io
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from beambench.sim.models.registry import make_beam_model
from beambench.sim.scenes.release import G, build_release_spec, static_equilibrium

if TYPE_CHECKING:
    from beambench.studies.fit.space import ParamSpace, ReleaseData

CONFIDENCE = 0.95  # two-sided level of the reported intervals
SHIFT = "release_shift"  # the release instant's offset (ms): data time − simulated time
# SI value × scale = the value in the optimizer's (and the report's) unit
UNITS: dict[str, tuple[float, str]] = {
    "k": (1.0, "N·m/rad"),
    "b": (1e3, "mN·m·s/rad"),
    "l1": (1e3, "mm"),
    "l2": (1e3, "mm"),
    "l2_share": (1.0, ""),
    "youngs_modulus": (1e-6, "MPa"),
    "beta": (1e3, "ms"),
    SHIFT: (1e3, "ms"),
}


@dataclass
class SysidFit:
    """A finished least-squares fit: the search vector ``x`` (:class:`ParamSpace` coordinates), the release
    shift (s), each fitted parameter's value and ``CONFIDENCE`` interval (SI, by name; ``release_shift``
    included when fitted), the fitted markers at the data times, the final RMS (mm) and what it cost."""

    x: np.ndarray
    shift_s: float
    values: dict[str, float]
    intervals: dict[str, tuple[float, float]]
    covariance: np.ndarray
    fitted: np.ndarray
    rms_mm: float
    rollouts: int
    iterations: int
    sim_wall_s: float
    status: str
    converged: bool


class ReleaseResidual:
    """The sysid residual of one release test for the variables of ``space`` (see the module docstring)."""

    def __init__(
        self,
        data: ReleaseData,
        space: ParamSpace,
        timestep: float = 2e-4,
        integrator: str = "implicitfast",
        nthread: int = 1,
        shift_window_s: float = 0.0,
    ) -> None:
        from mujoco import sysid

        self.data, self.space = data, space
        self.timestep, self.integrator = timestep, integrator
        self.shift_window = shift_window_s
        self.load_n = data.load_g * 1e-3 * G
        self.valid = np.isfinite(data.markers).all(axis=2)  # [n, M]
        if not self.valid.any():
            raise ValueError("no valid marker sample to fit")
        if np.any(np.diff(data.t) <= 0):
            raise ValueError("the marker samples' times do not increase strictly (repeated time stamps)")
        self.rollouts = 0
        self.sim_wall = 0.0
        spec = self._spec(space.params([v.coord(_mid(v.lo, v.hi, v.log)) for v in space.variables]))
        model = spec.compile()
        self._tip_cols = np.concatenate([np.arange(3) + int(model.sensor(n).adr[0]) for n in data.names])
        # the measured series in the model's sensor layout: the clamp ("stage") at the origin, the tip markers
        meas = np.zeros((len(data.t), model.nsensordata))
        meas[:, self._tip_cols] = data.markers.reshape(len(data.t), -1)
        mapping = sysid.TimeSeries.compute_all_sensor_mapping(model)
        measured = sysid.TimeSeries(np.asarray(data.t, float), meas, mapping)
        # the load is let go at t = 0: zero control for the simulated span (data, shift window, one step spare)
        span = float(np.max(data.t)) + shift_window_s + 2 * timestep
        n = max(3, math.ceil(span / timestep) + 2)
        control = sysid.TimeSeries(np.arange(n) * timestep, np.zeros((n, model.nu)))
        state0 = sysid.create_initial_state(model, static_equilibrium(model, self.load_n))
        self.sequences = sysid.ModelSequences("release", spec, "release", state0, control, measured)
        self.fn = sysid.build_residual_fn(
            models_sequences=[self.sequences],
            build_model=self._build,
            custom_rollout=self._rollout,
            modify_residual=self._residual,
            n_threads=max(1, nthread),
        )

    # ------------------------------------------------------------------------------------- parameters
    def parameters(self, x0: Sequence[float] | np.ndarray, shift0_s: float = 0.0) -> Any:
        """A :class:`mujoco.sysid.ParameterDict` starting at search vector ``x0`` and release shift ``shift0_s``
        (bounds: the variables' physical ones; the shift within the window, frozen if the window is zero)."""
        from mujoco import sysid

        params = sysid.ParameterDict()
        for var, xi in zip(self.space.variables, x0):
            scale = UNITS.get(var.name, (1.0, ""))[0]
            value = min(max(var.value(xi), var.lo), var.hi)
            params.add(sysid.Parameter(var.name, value * scale, var.lo * scale, var.hi * scale))
        w = max(self.shift_window, 1e-9) * 1e3
        s0 = float(np.clip(shift0_s * 1e3, -w, w))
        params.add(sysid.Parameter(SHIFT, s0, -w, w, frozen=self.shift_window <= 0))
        return params

    def search_vector(self, params: Any) -> np.ndarray:
        """The :class:`ParamSpace` search coordinates of the parameters' current values."""
        return np.array(
            [
                v.coord(float(params[v.name].value.item()) / UNITS.get(v.name, (1.0, ""))[0])
                for v in self.space.variables
            ]
        )

    # ---------------------------------------------------------------------------- the sysid callbacks
    def _spec(self, beam_params: Any) -> mujoco.MjSpec:
        beam = make_beam_model(self.space.model, beam_params)
        return build_release_spec(beam, self.data.twist_deg, self.integrator, self.timestep, len(self.data.names))

    def _build(self, params: Any, _spec: mujoco.MjSpec) -> mujoco.MjModel:
        return self._spec(self.space.params(self.search_vector(params))).compile()

    def _rollout(self, *, models: Sequence[mujoco.MjModel], datas: Sequence[mujoco.MjData], **kw: Any) -> Any:
        """sysid's rollout, each model released from its own loaded equilibrium."""
        from mujoco import sysid

        states = [sysid.create_initial_state(m, static_equilibrium(m, self.load_n)) for m in models]
        t0 = time.perf_counter()
        out = sysid.sysid_rollout(
            models=models,
            datas=datas,
            control_signal=kw["control_signal"],
            initial_states=states,
            rollout_signal_mapping=kw["rollout_signal_mapping"],
            rollout_state_mapping=kw["rollout_state_mapping"],
            ctrl_mapping=kw["ctrl_mapping"],
        )
        self.sim_wall += time.perf_counter() - t0
        self.rollouts += len(models)
        return out

    def _residual(
        self, params: Any, predicted: Any, measured: Any, model: mujoco.MjModel, _return_all: bool, **_: Any
    ) -> tuple[np.ndarray, Any, Any]:
        """Simulated minus measured marker coordinates (mm) at the valid samples; the prediction as a series
        on the data's times in the measured layout."""
        from mujoco import sysid

        shift = float(params[SHIFT].value.item()) * 1e-3
        h = float(model.opt.timestep)
        t_sensor = predicted.times - h  # sensor row k: the state before step k
        pos = np.clip((self.data.t - shift - t_sensor[0]) / h, 0.0, len(t_sensor) - 1.000001)
        i = pos.astype(int)
        w = (pos - i)[:, None]
        rows = predicted.data[:, self._tip_cols]
        pred = rows[i] * (1 - w) + rows[i + 1] * w  # before the release: row 0, the loaded equilibrium
        full = np.zeros_like(measured.data)
        full[:, self._tip_cols] = pred
        diff = (pred.reshape(self.data.markers.shape) - self.data.markers)[self.valid]
        return diff.ravel() * 1e3, sysid.TimeSeries(measured.times, full, measured.signal_mapping), measured

    # ------------------------------------------------------------------------------------------ fitting
    def fit(
        self,
        x0: Sequence[float] | np.ndarray,
        shift0_s: float = 0.0,
        max_iters: int = 40,
        progress: Callable[[int, float], None] | None = None,
    ) -> SysidFit:
        """Levenberg–Marquardt from ``x0`` (``mujoco.sysid.optimize``), then the intervals at the optimum."""
        from mujoco import sysid

        start = self.parameters(x0, shift0_s)
        nres = int(self.valid.sum()) * 3
        count = nres // 3
        trace: list[Any] = []
        log = io.StringIO()  # the backend's per-iteration log (it needs full verbosity for the Jacobian)

        def on_iter(log: list[Any]) -> None:
            trace[:] = log
            if progress is not None:
                progress(len(log), math.sqrt(2 * float(log[-1].objective) / count) * 1e-3)

        fitted_params, result = sysid.optimize(
            start,
            self.fn,
            optimizer="mujoco",
            verbose=False,
            max_iters=max_iters,
            output=log,
            x_scale="jac",  # MPa, ms, mm … each column scaled by its Jacobian norm
            # raise the damping √10× per rejected step, not the default 10^0.1: from a screen start the first
            # Gauss–Newton steps overshoot, and 1.26× steps spent ~40 % of a rod fit's rollouts on rejections
            mu_factor=10**0.5,
            iter_callback=on_iter,
        )
        ended = next((ln for ln in log.getvalue().splitlines() if ln.startswith("Terminated")), "")
        # "insufficient reduction": no step lowers the error any more — at the noise floor, the usual end
        converged = max_iters == 0 or any(m in ended for m in ("tol.", "insufficient reduction"))
        final = trace[-1]
        r = np.asarray(final.residual, float).ravel()
        cov, half = sysid.calculate_intervals([r], np.asarray(result.jac), alpha=1 - CONFIDENCE)
        names = fitted_params.get_non_frozen_parameter_names()
        values, intervals = {}, {}
        for name, value, hw in zip(names, fitted_params.as_vector(), half):
            scale = UNITS.get(name, (1.0, ""))[0]
            values[name] = float(value) / scale
            intervals[name] = (float(value - hw) / scale, float(value + hw) / scale)
        # the fitted markers at the optimum (one more rollout: the residual's prediction series)
        _, preds, _ = self.fn(fitted_params.as_vector(), fitted_params)
        fitted = preds[0][0].data[:, self._tip_cols].reshape(self.data.markers.shape)
        return SysidFit(
            self.search_vector(fitted_params),
            float(fitted_params[SHIFT].value.item()) * 1e-3,
            values,
            intervals,
            np.asarray(cov),
            fitted,
            math.sqrt(float(r @ r) / count),
            self.rollouts,
            max(0, len(trace) - 1),
            self.sim_wall,
            f"least squares: {ended.split(':', 1)[-1].split(' y:')[0].strip() or 'no iteration'} "
            f"({len(trace) - 1} iterations, {nres} residuals)",
            converged,
        )


def _mid(lo: float, hi: float, log: bool) -> float:
    return math.sqrt(lo * hi) if log else 0.5 * (lo + hi)
