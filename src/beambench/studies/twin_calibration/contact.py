"""The contact rig in ``beambench calibrate sim`` (registers itself; :mod:`.rig`).

Targets: ``rig: contact`` transitions (``calibration/paper_contact_targets.yaml``) or a contact session.
Unknowns (:data:`CONTACT_UNKNOWNS`, each with its bounds and how it goes into the prior parameter set): the
stiffness and damping scales, the preload (the gap follows from the static sag), the sole's friction and, opt-in,
the load frame's mass and the load's offset. The map is a stepped sweep as ``beambench run`` steps it
(:func:`simulate_contact`), judged by :func:`~.contact_objective.contact_objective`; the verify stage runs the
written protocol as the user will (:mod:`.written_run`).

Adding an unknown is one entry of :data:`CONTACT_UNKNOWNS` (docs/extending.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pandas as pd
import yaml

from beambench.sim.settings import SimSettings
from beambench.studies.twin_calibration.contact_objective import contact_checks, contact_landmarks, contact_objective
from beambench.studies.twin_calibration.protocol_out import CalibratedSet, extended_sweep, write_calibrated_protocol
from beambench.studies.twin_calibration.rig import CalibratableRig, CalibrationBase, register_rig, stepping_cost
from beambench.studies.twin_calibration.targets import (
    CalibrationInputError,
    Targets,
    contact_session_targets,
    contact_targets,
)
from beambench.studies.twin_calibration.written_run import run_written_protocol
from beambench.studies.unknowns import Override, Unknown, apply_values

if TYPE_CHECKING:
    from beambench.sim.models.params import BeamParams


@dataclass(frozen=True)
class RigValue:
    """The prior set's own value of a rig parameter (its rig block, else the scene's default), in the unknown's
    unit (``field / si``)."""

    field: str
    si: float = 1.0

    def __call__(self, params: BeamParams) -> float:
        from beambench.sim.scene_params import RigParams

        return float(getattr(RigParams.with_overrides(params.rig), self.field)) / self.si


def neutral(params: BeamParams) -> float:
    """The prior set's own value of a scale: 1."""
    return 1.0


def scale_friction(params: BeamParams, value: float) -> BeamParams:
    """The sole's friction scaled from the prior's own (its rig block, else the scene's default)."""
    from beambench.sim.scene_params import RigParams

    friction = float(RigParams.with_overrides(params.rig).friction) * float(value)
    return replace(params, rig={**params.rig, "friction": friction})


# The contact rig's unknowns. A rod's damping is b = beta·k: b_scale moves beta, k_scale moves E (and k), beta stays.
CONTACT_UNKNOWNS = (
    Unknown(
        "b_scale",
        0.25,
        4.0,
        log=True,
        default=1.0,
        doc="multiplies the prior set's b and b_twist",
        effect=Override(("b", "b_twist", "beta"), scale=True),
        own=neutral,
    ),
    # k alone moves no edge at a fixed interference (docs/contact-twin.md): fixed at 1 unless named
    Unknown(
        "k_scale",
        0.05,
        1.6,
        log=True,
        default=1.0,
        doc="multiplies the prior set's k and k_twist (a rod's Young's modulus, which sets all its springs)",
        effect=Override(("k", "k_twist", "material.youngs_modulus"), scale=True),
        own=neutral,
        fitted_by_default=False,
    ),
    Unknown(
        "preload_mm",
        -0.3,
        1.0,
        unit="mm",
        doc="static interference of the foot with the plate: sag under gravity − gap (the gap follows)",
    ),
    # opt-in (``--free``), when not fitted the prior set keeps its own value: the load frame's own mass and the
    # load's offset along the stage travel (paper: the 20 g sits "at the lower left corner of the load frame";
    # neither the frame's mass nor the offset is given)
    Unknown(
        "frame_mass_g",
        0.0,
        15.0,
        unit="g",
        default=0.0,
        opt_in=True,
        doc="the load frame's own mass (rig.frame_mass)",
        effect=Override(("rig.frame_mass",), si=1e-3),
        own=RigValue("frame_mass", 1e-3),
    ),
    Unknown(
        "mass_dx_mm",
        -5.0,
        25.0,
        unit="mm",
        default=0.0,
        opt_in=True,
        doc="the 20 g load's offset along x (rig.mass_dx)",
        effect=Override(("rig.mass_dx",), si=1e-3),
        own=RigValue("mass_dx", 1e-3),
    ),
    Unknown(
        "mass_dy_mm",
        -30.0,
        30.0,
        unit="mm",
        default=0.0,
        opt_in=True,
        doc="the 20 g load's offset along y, the beam's axis (rig.mass_dy)",
        effect=Override(("rig.mass_dy",), si=1e-3),
        own=RigValue("mass_dy", 1e-3),
    ),
    Unknown(
        "friction_scale",
        0.7,
        1.15,
        log=True,
        default=1.0,
        doc="multiplies the sole's effective friction (rig.friction): with the preload the pair that decides how "
        "far up the sole stays stuck (the continuous edge) with little effect on the ½ and ⅓ edges "
        "(docs/contact-twin.md); above ~7 the foot can stick during the settle with too little force",
        effect=scale_friction,
        own=neutral,
    ),
)


def contact_base(targets: Targets) -> CalibrationBase:
    """The fixed part of the contact twin: the session's protocol (else the shipped contact sweep) with its sweep
    extended to the targets (how the written protocol runs), simulated as ``beambench run`` simulates it (one
    :func:`~beambench.sim.protocol_slice.sim_slice`: model, ``auto`` included, integrator, timestep plan,
    twist, amplitude, windows, noise and seed); the prior parameter set is the session's, else the protocol's."""
    from beambench.acquisition.protocol.schema import Sweep, parse_protocol
    from beambench.common.resources import shipped_dir
    from beambench.session.slices import sim_slice

    text = targets.protocol_text or (shipped_dir("protocols") / "contact_sweep.yaml").read_text()
    try:
        proto = parse_protocol(text, targets.source)
    except ValueError as exc:
        raise CalibrationInputError(str(exc)) from None
    sweep = extended_sweep(yaml.safe_load(text), targets).get("sweep", {})
    try:
        written = proto.model_copy(update={"sweep": Sweep.model_validate(sweep)})
    except ValueError as exc:
        raise CalibrationInputError(f"{targets.source}: sweep: {exc}") from None
    try:
        sim = sim_slice(written)
    except ValueError as exc:
        raise CalibrationInputError(f"{targets.source}: {exc}") from None
    params = targets.prior.get("params", sim.params)
    freqs = tuple(float(f) for f in written.sweep.values()) if written.sweep is not None else ()
    return CalibrationBase(sim.model, str(params), sim.settings, freqs, sim.tolerance_mm)


def prior_params(base: CalibrationBase) -> BeamParams:
    """The prior parameter set."""
    from beambench.sim.models.params import load_params
    from beambench.sim.models.registry import model_family

    return load_params(base.params, model=model_family(base.model))


def contact_prior(base: CalibrationBase) -> dict[str, float]:
    """The prior set's own values of the contact unknowns (scales 1; its rig block, else the scene's defaults)."""
    p = prior_params(base)
    return {u.name: u.own(p) for u in CONTACT_UNKNOWNS if u.own is not None}


def contact_boxes(base: CalibrationBase) -> dict[str, tuple[float, float]]:
    """The prior set's physical ranges (its ``bounds:``) as the unknowns' boxes (``CalibratableRig.boxes``): the
    preload from h' (``rig.plate_gap``) at the prior's own static sag, the stiffness scale from the Young's modulus,
    the damping scale from ``beam.beta``, the
    friction scale from ``rig.friction``, the frame mass and the load's offset from theirs. Empty for a set
    without bounds. (The preload box is the gap's at the prior's sag; :func:`simulate_contact` keeps the gap
    inside h' wherever the other unknowns move the sag.)"""
    from beambench.sim.models.registry import make_beam_model
    from beambench.sim.scene_params import RigParams
    from beambench.sim.scenes.contact_regimes import static_sag

    p = prior_params(base)
    b = p.bounds
    if not b:
        return {}
    rig = RigParams.with_overrides(p.rig)
    out: dict[str, tuple[float, float]] = {}
    if "rig.plate_gap" in b:
        sag = static_sag(make_beam_model(base.model, p), rig, base.sim.twist_deg)
        gap = b["rig.plate_gap"]
        out["preload_mm"] = (1e3 * (sag - gap.max), 1e3 * (sag - gap.min))
    modulus = p.value("beam.material.youngs_modulus")
    if "beam.material.youngs_modulus" in b and modulus:
        e = b["beam.material.youngs_modulus"]
        out["k_scale"] = (e.min / modulus, e.max / modulus)
    beta = p.value("beam.beta")
    if "beam.beta" in b and beta:
        out["b_scale"] = (b["beam.beta"].min / beta, b["beam.beta"].max / beta)
    if "rig.friction" in b and rig.friction > 0:
        out["friction_scale"] = (b["rig.friction"].min / rig.friction, b["rig.friction"].max / rig.friction)
    if "rig.frame_mass" in b:
        out["frame_mass_g"] = (1e3 * b["rig.frame_mass"].min, 1e3 * b["rig.frame_mass"].max)
    for axis in ("dx", "dy"):
        if f"rig.mass_{axis}" in b:
            out[f"mass_{axis}_mm"] = (1e3 * b[f"rig.mass_{axis}"].min, 1e3 * b[f"rig.mass_{axis}"].max)
    return out


def physical_gap(params: BeamParams, gap: float) -> float:
    """``gap`` kept inside the set's physical h' (``rig.plate_gap`` bounds; unchanged without them)."""
    bound = params.bounds.get("rig.plate_gap")
    return gap if bound is None else min(max(gap, bound.min), bound.max)


def contact_verify(base: CalibrationBase) -> tuple[list[float], SimSettings]:
    """The written protocol's sweep and windows (``CalibratableRig.verify``)."""
    return list(base.frequencies), base.sim


def calibrated_params(base: CalibrationBase, values: dict[str, float]) -> BeamParams:
    """The prior :class:`BeamParams` with the fitted values applied."""
    return apply_values(prior_params(base), CONTACT_UNKNOWNS, values)


def simulate_contact(
    base: CalibrationBase, values: dict[str, float], frequencies: list[float], sim: SimSettings
) -> dict:
    """The contact twin's regime map at ``frequencies`` for the fitted ``values`` (runs in a worker): the gap h'
    is the static sag minus the preload; the map is a *stepped* sweep in rising frequency
    (:func:`beambench.sim.scenes.contact_regimes.stepped_regime_map`: the scene, drive and timestep plan of
    ``beambench run``, the state carried from step to step) classified from the normal force as ``beambench
    analyze`` does; the load cells' noise (and seed) as ``sim`` says (a stage's settings keep the written
    protocol's): with noise the contact threshold is 8σ instead of 20 mN, which moves labels at the continuous
    edge. Maps of every frequency from rest (``regime_map``) put the continuous edge up to ~6 Hz lower than the
    stepped run of the same protocol: a calibration fitted on them missed its targets once run
    (bench_calibrate.py's history)."""
    from beambench.sim.models.registry import make_beam_model
    from beambench.sim.scene_params import RigParams
    from beambench.sim.scenes.contact_regimes import ContactTwin, static_sag, stepped_regime_map

    params = calibrated_params(base, values)
    beam = make_beam_model(base.model, params)
    sag = static_sag(beam, RigParams.with_overrides(params.rig), sim.twist_deg)
    gap = physical_gap(params, sag - values.get("preload_mm", 0.0) * 1e-3)
    twin = ContactTwin(base.model, params, {"plate_gap": gap})
    table = stepped_regime_map(sorted(frequencies), sim, twin, tolerance_mm=base.tolerance_mm)
    table = table.astype({"tangential_sign": float, "touchdown_direction": float})
    return {"steps": table.to_dict("records"), "extras": {"gap_mm": gap * 1e3, "sag_mm": sag * 1e3}}


def contact_summary(steps: pd.DataFrame) -> dict:
    from beambench.sim.scenes.contact_regimes import transitions

    tr = transitions(steps["frequency_hz"].to_numpy(float), list(steps["regime"].astype(str)))
    return {**tr, "map": " ".join(f"{f:g}:{r}" for f, r in zip(steps["frequency_hz"], steps["regime"]))}


def write_contact_protocol(
    base: CalibrationBase, values: dict[str, float], extras: dict[str, Any], targets: Targets, out_dir: Path, name: str
) -> Path:
    """The contact rig's outputs (:func:`.protocol_out.write_calibrated_protocol`): its rig block and
    ``sim.plate_gap_mm`` carry the fitted gap."""
    p = calibrated_params(base, values)
    gap_mm = float(extras["gap_mm"])
    cal = CalibratedSet(
        params=p,
        rig_block={**p.rig, "plate_gap": round(gap_mm * 1e-3, 7)},
        values=values,
        prior=base.params,
        model=base.model,
        shipped_protocol="contact_sweep.yaml",
        sim_extra={"plate_gap_mm": round(gap_mm, 4)},
        params_note=".",
        protocol_note="sim.params points at the calibrated parameter set; sim.plate_gap_mm is the fitted gap.",
    )
    return write_calibrated_protocol(cal, targets, out_dir, name)


# CPU seconds per simulated second of a contact map where the shipped stepping costs hold no row for its model
# (rod5g at 5e-5 s, PGS: 0.11–0.13 in sim_backend/step_costs.csv)
CONTACT_CPU_PER_SIM_S = 0.13


def contact_cpu_per_sim_s(base: CalibrationBase, sim: SimSettings) -> float:
    """A contact map's CPU seconds per simulated second on one idle core (the search's budget clock)."""
    from beambench.sim.scenes.contact_screen import MAX_DT

    return stepping_cost("contact", base.model, sim, MAX_DT, CONTACT_CPU_PER_SIM_S)


# ``--quick`` on the contact rig: the whole search within its budget, the verify stage's two written-protocol runs
# (one round on two workers, ~40 CPU-s each for the paper's 294 s sweep) reserved first at their measured cost
# (written_factor 1.15 and WRITTEN_EXTRA_S: evaluate.py); the coarse stage gets all the rest (its lines and
# landmark steps all of it); what is left when the verify starts verifies more candidates (up to four); the
# verdict's seed spread is the verify's two seeds. No fine stage: the verify runs the best distinct coarse points
# as the written protocol (the truth the fine maps approximated); on the paper's targets the fine maps cost ~5
# coarse maps each and the verify chose the same point with and without them. The coarse maps: 1 Hz steps,
# 0.4 + 0.6 s windows at 1e-4 s (2.6 CPU-s a map on the paper's targets, 3-42 Hz, against 3.3 with 0.5 + 0.8 s);
# on 15 points whose written runs were known their landmarks were about as close to the written maps' as with
# 0.5 + 0.8 s; 0.3 + 0.5 s, or 2e-4 s with 0.4 + 0.6 s, moved them twice as far (docs/evidence.md)
CONTACT_QUICK: tuple[tuple[str, Any], ...] = (
    ("budget_s", 120.0),
    ("written_factor", 1.15),
    ("plan_finish", True),
    ("verify_top", 4),
    ("verify_fill", True),
    ("refine_top", 0),
    ("coarse_timestep", 1e-4),
    ("coarse_settle_s", 0.4),
    ("coarse_record_s", 0.6),
    ("spread_seeds", 2),
    ("line_share", 0.55),
    ("landmark_share", 0.55),
)


@register_rig
def contact_rig() -> CalibratableRig:
    """The contact rig as the calibrator knows it."""
    return CalibratableRig(
        name="contact",
        unknowns=CONTACT_UNKNOWNS,
        simulate=simulate_contact,
        objective=contact_objective,
        base=contact_base,
        write=write_contact_protocol,
        summary=contact_summary,
        bracket="preload_mm",
        verify=contact_verify,
        run_written=run_written_protocol,
        prior=contact_prior,
        landmarks=contact_landmarks,
        checks=contact_checks,
        boxes=contact_boxes,
        quick=CONTACT_QUICK,
        file_targets=contact_targets,
        session_targets=contact_session_targets,
        cpu_per_sim_s=contact_cpu_per_sim_s,
    )
