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

import numpy as np
import pandas as pd

CHART_FREQS = (16.0, 20.0, 24.0, 26.0, 30.0, 38.0)
CHART_SETTLE_S, CHART_RECORD_S = 1.0, 2.0
FORMULATIONS: dict[str, dict[str, float | bool]] = {
    "soft 1 ms": {},
    "matched 1 ms": {"contact_matched": True},
    "soft 2 ms": {"contact_timeconst": 0.002},
}
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
    from beambench.sim.scenes.contact_regimes import Classifier, StepWindow
    from beambench.sim.scenes.contact_rig import ContactRigSim

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


def chart_points(
    models: tuple[str, ...] = ("prb3", "rod3g", "rod5g", "rod10"),
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
        rod10 = [k for k in runs if k[0] == "rod10" and k[1] == form and k[2] == "implicitfast"]
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


def chart_figure(table: pd.DataFrame, out: Path) -> None:
    """Speed against accuracy: CPU per simulated second against the in-contact-fraction error (own 4× finer run;
    rod10) and the labels from 23 Hz up against rod10; unstable points listed with their reason."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = summarize(table)
    marks = {"prb3": "s", "rod3g": "^", "rod5g": "o", "rod10": "D"}
    colours = dict(zip(FORMULATIONS, ("tab:blue", "tab:orange", "tab:green")))
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.6), layout="constrained")
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
        ax.set_xscale("log")
        if log:
            ax.set_yscale("log")
            ax.axhline(0.03, color="grey", lw=0.8, ls="--")
        ax.set(xlabel="CPU s per simulated s", ylabel=label)
    for m, mk in marks.items():
        axes[0].scatter([], [], marker=mk, color="k", label=m)
    for f, c in colours.items():
        axes[0].scatter([], [], marker="o", color=c, label=f)
    axes[0].scatter([], [], marker="o", facecolors="none", edgecolors="k", label="implicit integrator")
    axes[0].legend(fontsize=7, loc="upper right")
    bad = s[~s["stable"]]
    note = "; ".join(f"{r.model} {r.formulation} {r.timestep:g}: {r.reason}" for r in bad.itertuples())[:300]
    fig.suptitle(
        f"Contact rig, reduced stepped sweep ({len(CHART_FREQS)} steps {CHART_FREQS[0]:g}-{CHART_FREQS[-1]:g} Hz, "
        f"{CHART_SETTLE_S:g} + {CHART_RECORD_S:g} s); marker size: timestep (1.6e-3 … 1.25e-5 s); dashed: 0.03"
        + (f"\nunstable: {note}" if note else "\nno point went unstable")
        + "; prb3 (the paper's fit) does not reach the plate on this rig: no error to show (drawn at 1e-3)",
        fontsize=9,
    )
    fig.savefig(out, dpi=110)
    plt.close(fig)
