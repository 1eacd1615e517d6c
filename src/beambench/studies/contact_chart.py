"""The contact scene's speed/accuracy chart: model × contact formulation × integrator × timestep on the shipped
contact twin's rig, measured on what the analysis reports.

Each point runs a reduced stepped sweep (:data:`CHART_FREQS`, the state carried from step to step as ``beambench
run`` does; shorter windows than the shipped 2 + 5 s) through :class:`~beambench.sim.scenes.contact_rig.ContactRigSim`
and keeps, per step, the regime label and in-contact fraction (classified as
:func:`~beambench.sim.scenes.contact_regimes.stepped_regime_map` does), the mean tangential force in contact, the
foot's lift-off height (the highest the contact corner rises above the plate in the record window) and the CPU
time. :func:`summarize` compares each point with its own run at a 4× finer timestep and with the finest rod10 run
of the same formulation. The rows are cached in a CSV (``sim_backend/contact_chart.csv``), which
:func:`chart_figure` draws.

Formulations (:data:`FORMULATIONS`): MuJoCo's soft contact at the twin's physical time constant (1 ms), the same
contact with its spring–damper matched to the timestep (``rig.contact_matched``), and the soft contact at the
softest physical time constant (2 ms, another point of the physical range, so other physics). PRB3 runs the
paper's release fit on the same rig block (its joints are fitted springs, not the physical set's E).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

CHART_FREQS = (16.0, 20.0, 24.0, 26.0, 30.0, 38.0)
CHART_SETTLE_S, CHART_RECORD_S = 1.0, 2.0
FORMULATIONS: dict[str, dict[str, float | bool]] = {
    "soft 1 ms": {},
    "matched 1 ms": {"contact_matched": True},
    "soft 2 ms": {"contact_timeconst": 0.002},
}
SHIPPED_PROTOCOL = "contact_sweep.yaml"  # the shipped contact sweep: its model, parameter set and timestep plan
# a point is within tolerance where its in-contact fraction is within this of the reference's at every step outside
# the lift-off band (the converged sweep's criterion); the labels are not part of it: on the chart's short windows
# the finest runs disagree with each other at 24 Hz (1/2 against irregular)
FRACTION_TOLERANCE = 0.03
COST_MARGIN = 0.10  # cheaper by less than this is a tie: single CPU timings of equal work differ by ~5 %
FROM_HZ = 23.0  # the labels above the lift-off band are the ones that converge
LIFT_OFF_BAND_HZ = (13.0, 22.0)  # chaotic at every timestep: a micrometre of gap flips its labels
COLUMNS = (
    "model",
    "formulation",
    "integrator",
    "timestep",
    "frequency_hz",
    "regime",
    "in_contact_fraction",
    "mean_tangential_n",
    "lift_off_mm",
    "ok",
    "reason",
    "cpu_s",
)


@dataclass(frozen=True)
class ChartPoint:
    model: str
    formulation: str
    integrator: str
    timestep: float


def twin_for(model: str, formulation: str) -> object:
    """The contact twin a point runs: the shipped physical set (PRB3: the paper's fit on the same rig block)."""
    from beambench.sim.models.params import load_params
    from beambench.sim.models.registry import model_family
    from beambench.sim.scenes.contact_regimes import ContactTwin

    over = {**FORMULATIONS[formulation], "max_timestep": 0.0}
    if model.startswith("prb"):
        rig = load_params("physical", model="rod").rig
        bp = dataclasses.replace(load_params("paper", model=model_family(model)), rig=dict(rig))
        return ContactTwin(model, bp, over)
    return ContactTwin(model, "physical", over)


def run_point(p: ChartPoint, freqs: tuple[float, ...] = CHART_FREQS) -> list[dict]:
    """One point's reduced stepped sweep: a row per step (:data:`COLUMNS`)."""
    from beambench.acquisition.streams import CONTACT_MARKERS
    from beambench.sim.engine.stepping import quiet_mujoco_warnings
    from beambench.sim.scenes.contact_rig import ContactRigSim
    from beambench.sim.scenes.step_regime import Classifier, StepWindow

    bm, rig = twin_for(p.model, p.formulation).build()  # type: ignore[attr-defined]
    plate_top = -(rig.foot_length + rig.plate_gap)
    foot = CONTACT_MARKERS.index("foot")
    rows: list[dict] = []
    base = dataclasses.asdict(p)
    c0 = time.process_time()
    with quiet_mujoco_warnings() as warnings:
        scene = ContactRigSim(bm, 90.0, rig.plate_gap, 0.002, rig, p.integrator, timestep=p.timestep)
        t_now, failed = 0.0, ""
        try:
            for f in freqs:
                row = {**base, "frequency_hz": f, "ok": False, "reason": failed}
                if failed:
                    rows.append(row)
                    continue
                c1 = time.process_time()
                scene.set_frequency(f)
                scene.advance_to(t_now + CHART_SETTLE_S)
                tr = scene.advance_to(t_now + CHART_SETTLE_S + CHART_RECORD_S)
                t_now += CHART_SETTLE_S + CHART_RECORD_S
                keep = tr.t > t_now - CHART_RECORD_S
                force = tr.channels["force_nt"][keep]
                z = tr.channels["markers"][keep, foot, 2]
                if warnings or not (np.isfinite(force).all() and np.isfinite(z).all()):
                    failed = " ".join((warnings[0] if warnings else "non-finite state").split())[:80]
                    rows.append(row | {"reason": failed})
                    continue
                w = StepWindow(
                    f,
                    p.timestep,
                    float(tr.t[keep][0]) - p.timestep,
                    force[:, 0],
                    force[:, 1],
                    tr.channels["markers"][keep, foot, 0],
                )
                got = Classifier().classify(w)
                rows.append(
                    row
                    | {
                        "regime": got["regime"],
                        "in_contact_fraction": got["in_contact_fraction"],
                        "mean_tangential_n": got["mean_tangential_n"],
                        "lift_off_mm": float(max(0.0, (z - plate_top).max()) * 1e3),
                        "ok": True,
                        "cpu_s": time.process_time() - c1,
                    }
                )
        finally:
            scene.physics.close()
    for r in rows:
        r.setdefault("cpu_s", np.nan)
        r["point_cpu_s"] = time.process_time() - c0
    return rows


REFERENCE_MODEL = "rod10"  # the accuracy reference: its finest run of each formulation (the ``rod10_*`` columns)


def chart_points(
    models: tuple[str, ...] = ("prb3", "rod3g", "rod5g", REFERENCE_MODEL),
    timesteps: tuple[float, ...] = (1.6e-3, 8e-4, 4e-4, 2e-4, 1e-4, 5e-5),
) -> list[ChartPoint]:
    """The grid: every model × formulation with ``implicitfast`` at each timestep and its 4× finer run; the
    shipped model with the ``implicit`` integrator too."""
    fine = tuple(sorted({dt / 4 for dt in timesteps} | set(timesteps), reverse=True))
    pts = [ChartPoint(m, f, "implicitfast", dt) for m in models for f in FORMULATIONS for dt in fine]
    pts += [ChartPoint("rod5g", "soft 1 ms", "implicit", dt) for dt in fine]
    return pts


def run_chart(points: list[ChartPoint], workers: int = 2, progress: Callable[[str], None] = print) -> pd.DataFrame:
    """Every point (cheapest first) on a local process pool (:func:`beambench.studies.executor.make_executor`)."""
    from beambench.studies.executor import make_executor

    order = sorted(points, key=lambda p: (-p.timestep, p.model))
    rows: list[dict] = []
    with make_executor(workers, preload=(__name__,)) as pool:
        for p, got in zip(order, pool.executor.map(run_point, order)):
            rows += got
            ok = all(r["ok"] for r in got)
            progress(
                f"{p.model} {p.formulation} {p.integrator} {p.timestep:g}: {got[0]['point_cpu_s']:.1f} s CPU"
                + ("" if ok else f" unstable ({next(r['reason'] for r in got if not r['ok'])})")
            )
    return pd.DataFrame(rows)


def summarize(table: pd.DataFrame) -> pd.DataFrame:
    """One row per point: CPU per simulated second, and its accuracy against its own 4× finer run (``own_*``) and
    against the finest rod10 run of its formulation (``rod10_*``): labels equal (all steps; from 23 Hz), the
    largest in-contact-fraction and lift-off (mm) differences outside the lift-off band, the mean tangential-force
    difference (N) from 23 Hz. ``stable`` False with the ``reason`` where a run diverged."""
    keys = ["model", "formulation", "integrator", "timestep"]
    table = table.assign(timestep=table["timestep"].astype(float).round(12))
    runs: dict[tuple[str, str, str, float], pd.DataFrame] = {
        (str(k[0]), str(k[1]), str(k[2]), float(k[3])): g.sort_values("frequency_hz")  # type: ignore[arg-type]
        for k, g in table.groupby(keys)
    }
    out = []
    for (m, form, integ, dt), g in runs.items():
        row: dict = {"model": m, "formulation": form, "integrator": integ, "timestep": dt}
        row["stable"] = bool(g["ok"].all())
        row["reason"] = next((str(r) for r in g["reason"] if isinstance(r, str) and r), "")
        row["cpu_s_per_sim_s"] = float(g["point_cpu_s"].iloc[0]) / (len(g) * (CHART_SETTLE_S + CHART_RECORD_S))
        own = runs.get((m, form, integ, round(dt / 4, 12)))
        rod10 = [k for k in runs if k[0] == REFERENCE_MODEL and k[1] == form and k[2] == "implicitfast"]
        ref10 = runs[min(rod10, key=lambda k: k[3])] if rod10 else None
        for name, ref in (("own", own), ("rod10", ref10)):
            row |= _accuracy(g, ref, name) if ref is not None and ref["ok"].all() and row["stable"] else {}
        out.append(row)
    return pd.DataFrame(out)


def _accuracy(g: pd.DataFrame, ref: pd.DataFrame, name: str) -> dict[str, float]:
    f = g["frequency_hz"].to_numpy()
    lab, lab_r = g["regime"].astype(str).to_numpy(), ref["regime"].astype(str).to_numpy()
    above = f >= FROM_HZ
    out = (f < LIFT_OFF_BAND_HZ[0]) | (f > LIFT_OFF_BAND_HZ[1])
    ft, ft_r = g["mean_tangential_n"].to_numpy(float), ref["mean_tangential_n"].to_numpy(float)
    dft = np.abs(ft - ft_r)  # absolute: the mean tangential force crosses zero where its sign turns
    cf = np.abs(g["in_contact_fraction"].to_numpy(float) - ref["in_contact_fraction"].to_numpy(float))
    lift = np.abs(g["lift_off_mm"].to_numpy(float) - ref["lift_off_mm"].to_numpy(float))
    return {
        f"{name}_labels_equal": float((lab == lab_r).mean()),
        f"{name}_labels_equal_from_23hz": float((lab[above] == lab_r[above]).mean()),
        f"{name}_contact_fraction_err": float(np.nanmax(cf[out])),  # outside the lift-off band
        f"{name}_tangential_err_n": float(np.nanmean(dft[above])) if np.isfinite(dft[above]).any() else np.nan,
        f"{name}_lift_off_err_mm": float(np.nanmax(lift[out])),
    }


def shipped_point(protocol_file: Path | None = None) -> ChartPoint:
    """The shipped default as a chart point, read from the shipped contact protocol and its parameter set (not
    named here): its model, the formulation whose contact is the set's (time constant, damping ratio, matched or
    not), its integrator, and the timestep it runs at over the chart's frequencies (``sim.timestep``, else the
    measured plan's or the rig's policy, capped at the set's ``rig.max_timestep``). ValueError where the chart has
    no such point (a formulation it does not run, or several timesteps over its frequencies)."""
    from beambench.acquisition.protocol.schema import load_protocol
    from beambench.common.resources import shipped_dir
    from beambench.session.slices import sim_slice
    from beambench.sim.models.params import load_params
    from beambench.sim.models.registry import model_family
    from beambench.sim.scene_params import RigParams
    from beambench.sim.scenes.contact_rig import capped, default_timestep

    path = protocol_file or shipped_dir("protocols") / SHIPPED_PROTOCOL
    protocol, _ = load_protocol(path)
    sim = sim_slice(protocol)
    shipped = load_params(sim.params, model=model_family(sim.model)).rig
    rig = RigParams.with_overrides(shipped)
    contact = ("contact_timeconst", "contact_dampratio", "contact_matched")
    same = [
        name
        for name, over in FORMULATIONS.items()
        if all(getattr(RigParams.with_overrides({**shipped, **over}), k) == getattr(rig, k) for k in contact)
    ]
    if not same:
        raise ValueError(f"{path.name}: the chart runs no formulation with the contact of parameter set {sim.params}")
    if sim.timestep is not None:
        steps = {sim.timestep}
    else:
        base = sim.plan.timestep if sim.plan else default_timestep
        steps = {capped(base(f), rig.max_timestep) for f in CHART_FREQS}
    if len(steps) != 1:
        raise ValueError(f"{path.name}: {len(steps)} timesteps over the chart's frequencies ({sorted(steps)})")
    return ChartPoint(sim.model, same[0], sim.integrator, round(steps.pop(), 12))


def same_physics(table: pd.DataFrame, point: ChartPoint) -> pd.DataFrame:
    """The points that simulate ``point``'s physics (its model, and a formulation with its contact time constant
    and damping ratio: soft or matched to the timestep), any integrator and timestep, with ``cpu_s_per_sim_s``,
    ``stable`` and ``ref_contact_fraction_err``: the largest in-contact-fraction difference outside the lift-off band
    against the finest run of ``point``'s own model, formulation and integrator (the reference)."""
    keys = ["model", "formulation", "integrator", "timestep"]
    table = table.assign(timestep=table["timestep"].astype(float).round(12))
    contact = {k: v for k, v in FORMULATIONS[point.formulation].items() if k != "contact_matched"}
    forms = [f for f, o in FORMULATIONS.items() if {k: v for k, v in o.items() if k != "contact_matched"} == contact]
    own = table[(table["model"] == point.model) & table["formulation"].isin(forms)]
    ref_runs = own[(own["formulation"] == point.formulation) & (own["integrator"] == point.integrator)]
    ref = ref_runs[ref_runs["timestep"] == ref_runs["timestep"].min()].sort_values("frequency_hz")
    s = summarize(own)
    errs = []
    for _, r in s.iterrows():
        g = own[(own[keys] == r[keys].to_numpy()).all(axis=1)].sort_values("frequency_hz")
        ok = r["stable"] and bool(ref["ok"].all()) and len(g) == len(ref)
        errs.append(_accuracy(g, ref, "ref")["ref_contact_fraction_err"] if ok else np.nan)
    s["ref_contact_fraction_err"] = errs
    s.attrs["reference"] = ChartPoint(point.model, point.formulation, point.integrator, float(ref["timestep"].iloc[0]))
    return s


def front_check(table: pd.DataFrame, point: ChartPoint) -> tuple[pd.DataFrame, list[str]]:
    """``point`` against the points of its physics (:func:`same_physics`): within tolerance (stable, in-contact
    fraction within :data:`FRACTION_TOLERANCE` of the reference outside the lift-off band) and the cheapest such
    point? Returns that table with ``within`` and ``shipped`` columns, and one line per point that beats ``point``
    (within tolerance and cheaper by more than :data:`COST_MARGIN`), or ``point`` itself when it is out of
    tolerance or missing from the table; empty: ``point`` lies on the front."""
    s = same_physics(table, point)
    s["within"] = s["stable"] & (s["ref_contact_fraction_err"] <= FRACTION_TOLERANCE)
    s["shipped"] = (
        (s["model"] == point.model)
        & (s["formulation"] == point.formulation)
        & (s["integrator"] == point.integrator)
        & np.isclose(s["timestep"], point.timestep, rtol=1e-9, atol=0.0)
    )
    if not s["shipped"].any():
        return s, [f"the shipped point {point} is not in the chart's table"]
    me = s[s["shipped"]].iloc[0]
    if not me["within"]:
        return s, [f"the shipped point {point} is out of tolerance: {me['ref_contact_fraction_err']:.3f}"]
    cheaper = s[s["within"] & (s["cpu_s_per_sim_s"] < (1 - COST_MARGIN) * me["cpu_s_per_sim_s"])]
    return s, [
        f"{r.model} {r.formulation} {r.integrator} {r.timestep:g} s: {r.cpu_s_per_sim_s:.3f} CPU s per simulated s "
        f"against {me['cpu_s_per_sim_s']:.3f}, in-contact fraction within {r.ref_contact_fraction_err:.3f}"
        for r in cheaper.itertuples()
    ]


def chart_figure(table: pd.DataFrame, out: Path) -> None:
    """Speed against accuracy: CPU per simulated second against the in-contact-fraction error (own 4× finer run;
    rod10) and the labels from 23 Hz up against rod10; unstable points listed with their reason."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = summarize(table)
    marks = {"prb3": "s", "rod3g": "^", "rod5g": "o", "rod10": "D"}
    colours = dict(zip(FORMULATIONS, ("tab:blue", "tab:orange", "tab:green")))
    fig, grid = plt.subplots(2, 2, figsize=(13, 9), layout="constrained")
    axes = grid.ravel()
    shipped = shipped_point()
    at = s[
        (s["model"] == shipped.model)
        & (s["formulation"] == shipped.formulation)
        & (s["integrator"] == shipped.integrator)
        & np.isclose(s["timestep"], shipped.timestep, rtol=1e-9, atol=0.0)
    ]
    panels = (
        ("own_contact_fraction_err", "in-contact fraction error\nagainst its own 4× finer run", True),
        ("rod10_contact_fraction_err", "in-contact fraction error\nagainst rod10 (finest step)", True),
        ("rod10_labels_equal_from_23hz", "share of labels from 23 Hz\nequal to rod10's", False),
    )
    for ax, (col, label, log) in zip(axes, panels):
        for _, r in s.iterrows():
            if col not in r or not np.isfinite(r.get(col, np.nan)):
                continue
            y = max(float(r[col]), 1e-3) if log else float(r[col])
            filled = r["integrator"] == "implicitfast"
            c = colours[r["formulation"]]
            ax.scatter(
                r["cpu_s_per_sim_s"],
                y,
                marker=marks.get(r["model"], "o"),
                s=10 + 40 * np.log10(r["timestep"] / 1e-5),
                facecolors=c if filled else "none",
                edgecolors=c,
            )
        for star in at.itertuples():  # the shipped default, ringed
            y = getattr(star, col, np.nan)
            if np.isfinite(y):
                _star(ax, star.cpu_s_per_sim_s, max(y, 1e-3) if log else y)
        ax.set_xscale("log")
        if log:
            ax.set_yscale("log")
            ax.axhline(FRACTION_TOLERANCE, color="grey", lw=0.8, ls="--")
        ax.set(xlabel="CPU s per simulated s", ylabel=label)
    _front_panel(axes[3], table, shipped, colours)
    for m, mk in marks.items():
        axes[0].scatter([], [], marker=mk, color="k", label=m)
    for f, c in colours.items():
        axes[0].scatter([], [], marker="o", color=c, label=f)
    axes[0].scatter([], [], marker="o", facecolors="none", edgecolors="k", label="implicit integrator")
    axes[0].scatter([], [], marker="*", s=120, facecolors="none", edgecolors="k", label="shipped default")
    axes[0].legend(fontsize=7, loc="upper right")
    bad = s[~s["stable"]]
    note = "; ".join(f"{r.model} {r.formulation} {r.timestep:g}: {r.reason}" for r in bad.itertuples())[:300]
    fig.suptitle(
        f"Contact rig, reduced stepped sweep ({len(CHART_FREQS)} steps {CHART_FREQS[0]:g}-{CHART_FREQS[-1]:g} Hz, "
        f"{CHART_SETTLE_S:g} + {CHART_RECORD_S:g} s); marker size: timestep (1.6e-3 … 1.25e-5 s); dashed: {FRACTION_TOLERANCE:g}"
        + (f"\nunstable: {note}" if note else "\nno point went unstable")
        + "; prb3 (the paper's fit) does not reach the plate on this rig: no error to show (drawn at 1e-3)",
        fontsize=9,
    )
    fig.savefig(out, dpi=110)
    plt.close(fig)


def _star(ax: Any, x: Any, y: Any) -> None:
    """The shipped default's mark: a ringed star, on top."""
    ax.scatter(x, y, marker="*", s=260, facecolors="none", edgecolors="k", lw=1.2, zorder=5)


def _front_panel(ax: Any, table: pd.DataFrame, shipped: ChartPoint, colours: dict[str, str]) -> None:
    """The shipped physics' front: its points' cost against their in-contact-fraction error from the finest run,
    the cheapest-so-far envelope, the tolerance, and the shipped default with what (if anything) beats it."""
    s, beaten_by = front_check(table, shipped)
    ref = s.attrs["reference"]
    ok = s[np.isfinite(s["ref_contact_fraction_err"]) & ~np.isclose(s["timestep"], ref.timestep)]
    for r in ok.itertuples():
        c = colours[r.formulation]
        ax.scatter(
            r.cpu_s_per_sim_s,
            max(r.ref_contact_fraction_err, 1e-3),
            marker="o",
            s=10 + 40 * np.log10(r.timestep / 1e-5),
            facecolors=c if r.integrator == "implicitfast" else "none",
            edgecolors=c,
        )
    order = ok.sort_values("cpu_s_per_sim_s")
    best = np.minimum.accumulate(order["ref_contact_fraction_err"].to_numpy())  # the front: least error so far
    ax.step(order["cpu_s_per_sim_s"], np.maximum(best, 1e-3), where="post", color="k", lw=0.8, alpha=0.6)
    me = s[s["shipped"]]
    for r in me.itertuples():
        _star(ax, r.cpu_s_per_sim_s, r.ref_contact_fraction_err)
        ax.annotate(
            f"shipped: {r.integrator} {r.timestep:g} s",
            (r.cpu_s_per_sim_s, r.ref_contact_fraction_err),
            xytext=(8, -14),
            textcoords="offset points",
            fontsize=8,
        )
    ax.axhline(FRACTION_TOLERANCE, color="grey", lw=0.8, ls="--")
    ax.set(
        xscale="log",
        yscale="log",
        xlabel="CPU s per simulated s",
        ylabel=f"in-contact fraction error against\n{ref.model} {ref.formulation} {ref.integrator} {ref.timestep:g} s",
    )
    verdict = (
        "on the front: the cheapest point within tolerance" if not beaten_by else "beaten by " + "; ".join(beaten_by)
    )
    ax.set_title(
        f"The shipped physics ({shipped.model}, {shipped.formulation}; soft or matched): {verdict}",
        fontsize=8.5,
        wrap=True,
    )
