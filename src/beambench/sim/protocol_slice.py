"""The simulation slice of a protocol, made in one place: what the sim backend runs and what every study simulates.

:func:`sim_slice` turns a protocol into a frozen :class:`SimSlice`: the scene, the beam (model and parameter set,
``sim.model: auto`` resolved from the measured table), the windows, twist and amplitude in SI, the integrator and
timestep plan, the plate gap, thermal drift, noise, seed and device clocks. The sim backend builds its scene and
devices from it; a calibration simulates its ``model`` with its ``settings``, so a protocol's run and its
calibration cannot simulate different models.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pydantic import BaseModel

from beambench.acquisition.config import ClockModel, ConfigError, Protocol, Release, SimOptions, ThermalDrift
from beambench.acquisition.scenes import SceneInfo, foreign_option, runnable_names, scene_info
from beambench.sim.models.params import has_params
from beambench.sim.models.registry import model_family
from beambench.sim.selection import Plan, SelectionError, plan_sweep, table_models
from beambench.sim.settings import SimSettings

__all__ = ["AUTO_TOLERANCE_MM", "DeviceClocks", "SimSlice", "sim_slice"]

AUTO_TOLERANCE_MM = 0.1  # sim.model: auto without sim.tolerance_mm (about the mocap's noise)


@dataclass(frozen=True)
class DeviceClocks:
    """The simulated devices' clocks (offset, drift, jitter, latency)."""

    mocap: ClockModel = field(default_factory=ClockModel)
    loadcell: ClockModel = field(default_factory=ClockModel)
    motor: ClockModel = field(default_factory=ClockModel)


@dataclass(frozen=True)
class SimSlice:
    """One protocol's simulation, every choice made (SI units: s, deg, m)."""

    scene: str
    """The registered scene (the protocol's ``rig``)."""
    model: str
    """The beam model, ``auto`` already resolved."""
    params: str
    """The parameter set's name."""
    settings: SimSettings
    """Windows, twist, amplitude, integrator (the plan's, when there is one), fixed timestep, noise, seed."""
    plan: Plan | None = None
    """The measured plan (timestep per frequency; :mod:`beambench.sim.selection`), or None: the scene's policy."""
    tolerance_mm: float = AUTO_TOLERANCE_MM
    """The accuracy the plan was chosen for."""
    plate_gap_m: float | None = None
    """h' from the foot's unloaded position; None: the parameter set's."""
    thermal: ThermalDrift | None = None
    """The contact twin's thermal drift, or None: off."""
    release: Release = field(default_factory=Release)
    """The release test's load and markers."""
    segments: int = 1
    """Consecutive parts of the sweep computed in parallel (:mod:`beambench.backends.lookahead`)."""
    clocks: DeviceClocks = field(default_factory=DeviceClocks)
    """The simulated devices' clocks."""
    stage_amplitude_m: float | None = None
    """The stage amplitude the motor reports (scenes with a stage), else None."""

    @property
    def integrator(self) -> str:
        """The MuJoCo integrator (the plan's, else ``sim.integrator``)."""
        return self.settings.integrator or "implicitfast"

    @property
    def timestep(self) -> float | None:
        """The fixed ``sim.timestep``, or None: the plan's per frequency, else the scene's own."""
        h = self.settings.timestep
        return None if h is None or isinstance(h, tuple) else float(h)


def sim_slice(protocol: Protocol) -> SimSlice:
    """The simulation ``protocol`` describes; a bad choice (``auto`` on a scene without a measured table, a
    tolerance nothing meets, another scene's option) is a :class:`ConfigError` naming the field."""
    sim = protocol.sim
    info = scene_info(protocol.rig)
    _check_scene_options(info, sim)
    plan = _plan(protocol)
    settings = SimSettings(
        settle_s=float(protocol.settle_s),
        record_s=float(protocol.record_s),
        twist_deg=float(sim.twist_deg),
        amplitude_m=float(protocol.amplitude_mm) * 1e-3,
        integrator=plan.integrator if plan else str(sim.integrator),
        timestep=sim.timestep,
        noise=bool(sim.noise),
        seed=int(sim.seed),
    )
    return SimSlice(
        scene=info.name,
        model=plan.model if plan else sim.model,
        params=sim.params,
        settings=settings,
        plan=plan,
        tolerance_mm=sim.tolerance_mm or AUTO_TOLERANCE_MM,
        plate_gap_m=None if sim.plate_gap_mm is None else sim.plate_gap_mm * 1e-3,
        thermal=sim.thermal_drift,
        release=protocol.release,
        segments=sim.segments,
        clocks=DeviceClocks(sim.mocap_clock, sim.loadcell_clock, sim.motor_clock),
        stage_amplitude_m=settings.amplitude_m if info.stage else None,
    )


def _check_scene_options(info: SceneInfo, sim: SimOptions) -> None:
    """``sim.model: auto`` needs a measured table; another scene's options (set to other than their default) are
    refused with one line."""
    if sim.model == "auto" and not info.measured_table:
        tabled = " or ".join(n for n in runnable_names() if scene_info(n).measured_table)
        reason = f"auto chooses from the measured {tabled}-rig table (rig: {tabled}); name a model (prb3, rod10 …)"
        raise ConfigError("<protocol>", "sim.model", sim.model, reason)
    defaults = SimOptions.model_fields
    given = {k for k in sim.model_fields_set if getattr(sim, k) != defaults[k].default}
    foreign = foreign_option(info.name, given, "rig")
    if foreign is not None:
        option, reason = foreign
        value = getattr(sim, option)
        shown = value.model_dump(exclude_unset=True) if isinstance(value, BaseModel) else value
        raise ConfigError("<protocol>", f"sim.{option}", shown, reason)


def _plan(protocol: Protocol) -> Plan | None:
    """The measured plan of a scene with a measured table (the contact rig; :mod:`beambench.sim.selection`),
    within ``sim.tolerance_mm``:

    - ``sim.model: auto``: the cheapest (model, integrator, timestep per frequency); a tolerance nothing
      meets is a ConfigError;
    - a named model without ``sim.timestep``: the timestep each frequency needs for that model and
      integrator, or None (the rig's fixed policy) when the table does not cover them.

    None for scenes without a measured table and for a fixed ``sim.timestep``."""
    sim = protocol.sim
    auto = sim.model == "auto"
    if not scene_info(protocol.rig).measured_table or (not auto and sim.timestep is not None):
        return None
    tol = sim.tolerance_mm or AUTO_TOLERANCE_MM
    if auto:  # every model with a contact table whose family has the protocol's parameter set
        found = [m for m in table_models(protocol.rig) if has_params(sim.params, model_family(m))]
        models, integrators = (found or None), None
    else:
        models, integrators = [sim.model], [str(sim.integrator)]
    try:
        freqs = protocol.sweep.values() if protocol.sweep is not None else []
        return plan_sweep(protocol.rig, tol, freqs, models=models, integrators=integrators)
    except SelectionError as exc:
        if auto:
            raise ConfigError("<protocol>", "sim.tolerance_mm", tol, str(exc)) from None
        return None
