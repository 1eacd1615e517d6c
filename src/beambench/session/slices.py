"""Each layer's slice of a protocol, cut in one place: the backends and studies never see the whole protocol.

:func:`sim_slice` is the simulation (:class:`~beambench.sim.protocol_slice.SimSlice`: scene, model with ``auto``
resolved, windows, amplitude, integrator and timestep plan, plate gap, thermal drift, noise, seed, clocks);
:func:`rig_slices` adds what a device rig needs (the mocap's wired markers) for :func:`beambench.backends.build.build_rig`.
"""

from __future__ import annotations

from pydantic import BaseModel

from beambench.acquisition.clocks import DeviceClocks
from beambench.acquisition.protocol.backends import backend_info
from beambench.acquisition.protocol.scenes import SceneInfo, foreign_option, runnable_names, scene_info
from beambench.acquisition.protocol.schema import Backend, Protocol, SimOptions
from beambench.acquisition.streams import MOTOR
from beambench.backends.build import RigSlices
from beambench.backends.sim_streams import SIM_STREAMS
from beambench.common.yaml_config import MISSING, ConfigError, shorten
from beambench.sim.models.params import has_params
from beambench.sim.models.registry import model_family
from beambench.sim.protocol_slice import AUTO_TOLERANCE_MM, SimSlice
from beambench.sim.selection import Plan, SelectionError, plan_sweep, table_models
from beambench.sim.settings import SimSettings

__all__ = ["check_clocks", "rig_slices", "sim_slice"]


def rig_slices(protocol: Protocol, backend: Backend) -> RigSlices:
    """What ``backend`` builds its rig from: the simulation slice (not on hardware: its ``sim:`` options do not
    apply there) and the markers the mocap is wired to."""
    return RigSlices(
        sim=sim_slice(protocol) if backend_info(backend).simulates else None,
        markers=scene_info(protocol.rig).wired_markers,
        tracking=protocol.track is not None,
    )


def sim_slice(protocol: Protocol) -> SimSlice:
    """The simulation ``protocol`` describes; a bad choice (``auto`` on a scene without a measured table, a
    tolerance nothing meets, another scene's option) is a :class:`ConfigError` naming the field."""
    sim = protocol.sim
    info = scene_info(protocol.rig)
    _check_scene_options(info, sim)
    check_clocks(sim)
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
        clocks=DeviceClocks.of_mapping(sim.clocks),
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


def check_clocks(sim: SimOptions, file: str = "<protocol>") -> None:
    """Each key of ``sim.clocks`` names a simulated stream (the motor's or a registered one); else one line naming
    the field, the key and the streams there are."""
    known = [MOTOR, *SIM_STREAMS]
    for name in sim.clocks:
        if name not in known:
            reason = f"no simulated stream {shorten(name)} (the sim's streams: {', '.join(known)})"
            raise ConfigError(file, f"sim.clocks.{name[:40]}", MISSING, reason)


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
