"""Everything about a run that can be checked before anything moves, dry run included (one-line errors).

The protocol model (:mod:`beambench.acquisition.protocol.schema`) checks each field on its own; :func:`validate`
does the rest, once, and returns what the run is built from (:class:`Validated`: the step plan, each layer's
slices, the motor limits): the limits, the beam model name against the registry, that the parameter set exists and
loads, the scene's options and timestep plan, and the run's options (``--can-log``). Nothing here loads MuJoCo or
python-can, so a dry run checks every field without them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, fields
from pathlib import Path

from beambench.acquisition.capabilities import MotorLimits
from beambench.acquisition.protocol.backends import backend_info, backends_with
from beambench.acquisition.protocol.plan import Step, check_limits, motor_limits, plan
from beambench.acquisition.protocol.scenes import scene_info
from beambench.acquisition.protocol.schema import Backend, Protocol
from beambench.backends.build import RigSlices
from beambench.common.yaml_config import ConfigError, shorten
from beambench.devices.odrive.can_log import LOG_SUFFIXES
from beambench.session.slices import check_clocks, rig_slices
from beambench.sim.models.params import BeamParams, ParamsError, load_params
from beambench.sim.models.registry import model_family
from beambench.sim.scene_params import RigParams, WalkerParams


@dataclass(frozen=True)
class Validated:
    """A protocol checked for one backend, and what its run is built from."""

    steps: list[Step]
    """The step plan (:func:`beambench.acquisition.protocol.plan.plan`)."""
    slices: RigSlices
    """What the backend builds its rig from (the simulation slice with its timestep plan, the wired markers)."""
    limits: MotorLimits
    """What the runner holds the motor to."""


def validate(protocol: Protocol, backend: Backend, file: str = "<protocol>", can_log: Path | None = None) -> Validated:
    """Check ``protocol`` for a run on ``backend`` (with ``--can-log``): the first problem is a one-line
    :class:`ConfigError` naming the field; else the run's plan, slices and limits."""
    _check_fields(protocol, file, backend, can_log)
    try:
        slices = rig_slices(protocol, backend)
    except ConfigError as exc:  # the slices know the protocol, not its file: the line names the file
        if exc.file != "<protocol>" or not exc.field:
            raise
        raise ConfigError(file, exc.field, exc.value, exc.reason) from None
    return Validated(plan(protocol), slices, motor_limits(protocol))


def _reason(exc: Exception) -> str:
    """The reason part of a ``"<field> = <value>: <reason>"`` message."""
    text = str(exc)
    head, sep, tail = text.partition(": ")
    return tail if sep and " = " in head else text


def _check_overrides(params: BeamParams, rig: str, file: str, given: str) -> None:
    """The set's ``rig:`` block names contact-rig (or, on the walker, walker) parameters; ``walker:`` the walker's."""
    contact, walker = {f.name for f in fields(RigParams)}, {f.name for f in fields(WalkerParams)}
    known_rig = walker | contact if scene_info(rig).walks else contact
    for block, names, known in (("rig", params.rig, known_rig), ("walker", params.walker, walker)):
        unknown = sorted(set(names) - known)
        if unknown:
            reason = f"{block}.{unknown[0][:40]}: unknown {block} parameter (see the scene's RigParams or WalkerParams)"
            raise ConfigError(file, "sim.params", given, reason)
        switches = {f.name for cls in (RigParams, WalkerParams) for f in fields(cls) if f.type in (bool, "bool")}
        for key, value in names.items():
            if isinstance(value, bool) != (key in switches):
                kind = "true or false" if key in switches else "a number"
                raise ConfigError(file, "sim.params", given, f"{block}.{key} = {value}: must be {kind}")


def can_log_problem(path: Path) -> str | None:
    """Why ``path`` cannot take a new CAN log (checked before anything moves), or None. A log is a new regular
    file in a folder this process can write: never a device (``/dev/full``), a folder, or a file it would
    truncate."""
    if path.is_symlink() or path.exists():
        if path.is_dir():
            return "is a folder"
        if not path.is_file():
            return "is not a regular file (a device, a pipe or a broken link)"
        return "exists; give a new file (a CAN log is never overwritten)"
    folder = path.parent
    while not folder.exists() and folder != folder.parent:  # the folders the log would create
        folder = folder.parent
    if not folder.is_dir():
        return f"{folder} is not a folder"
    if not os.access(folder, os.W_OK | os.X_OK):
        return f"folder {folder} cannot be written (read-only or no permission)"
    return None


def _check_fields(protocol: Protocol, file: str, backend: str | None = None, can_log: Path | None = None) -> None:
    """Raise :class:`ConfigError` for the first problem: limits, ``sim.model``, ``sim.params``, ``sim.clocks``,
    ``--can-log``."""
    check_limits(protocol, file)
    sim = protocol.sim
    family = "prb3"
    if sim.model != "auto":
        try:
            family = model_family(sim.model)
        except ValueError as exc:
            raise ConfigError(file, "sim.model", sim.model, _reason(exc)) from None
    try:
        params = load_params(sim.params, model=family)
    except (ParamsError, OSError) as exc:
        raise ConfigError(file, "sim.params", sim.params, _reason(exc)) from None
    _check_overrides(params, protocol.rig, file, sim.params)
    check_clocks(sim, file)  # on every backend: a protocol is checked whole wherever it runs
    if can_log is not None:
        if backend is not None and not backend_info(backend).devices:
            on_can = " or ".join(backends_with("devices"))
            raise ConfigError("<cli>", "--can-log", str(can_log), f"needs an ODrive on CAN (--backend {on_can})")
        if can_log.suffix.lower() not in LOG_SUFFIXES:
            raise ConfigError("<cli>", "--can-log", shorten(str(can_log)), f"use a {' or '.join(LOG_SUFFIXES)} file")
        problem = can_log_problem(can_log)
        if problem is not None:
            raise ConfigError("<cli>", "--can-log", shorten(str(can_log)), problem)
