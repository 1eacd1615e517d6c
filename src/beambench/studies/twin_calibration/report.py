"""The report of a calibration (``beambench calibrate sim`` writes it beside the calibrated protocol): JSON and
Markdown with the parameters, their identifiability, every target against the twin with its verdict (met within
its tolerance or missed, and what limits a miss: :mod:`.verdict`), the objective per generation, and two
figures (the objective's history, the target and twin maps)."""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path

import pandas as pd

from beambench.sim.scenes.contact_regimes import IRREGULAR
from beambench.studies.twin_calibration.contact_objective import CONTINUOUS_LEVEL, regime_level
from beambench.studies.twin_calibration.evaluate import json_default
from beambench.studies.twin_calibration.search import Result
from beambench.studies.twin_calibration.targets import Targets
from beambench.studies.twin_calibration.verdict import all_met, closing_line


def write_report(result: Result, targets: Targets, out_dir: Path, name: str) -> Path:
    """``<name>_report.json`` / ``.md``, ``<name>_objective.png`` and ``<name>_maps.png`` beside the protocol;
    returns the Markdown report's path."""
    meas = targets.table
    twin = result.steps
    rep = {
        "rig": result.rig,
        "targets": {"source": targets.source, **{k: v for k, v in targets.scalars.items()}},
        "protocol": str(result.protocol),
        "objective": result.j,
        "objective_stage": result.j_stage,
        "verdict": {"all_met": all_met(result.verdicts), "targets": [v.to_dict() for v in result.verdicts]},
        "parameters": result.values,
        "extras": result.extras,
        "twin_summary": result.summary,
        "identifiability": result.identifiability,
        "history": result.history,
        "evaluations": {"new": result.evaluations, "reused_from_log": result.reused, "cpu_s": result.cpu_s},
        "wall_s": result.wall_s,
        "budget_clock_s": result.budget_clock_s,
        "settings": asdict(result.settings),
    }
    (out_dir / f"{name}_report.json").write_text(json.dumps(rep, indent=1, default=json_default))
    _figures(result, meas, twin, out_dir, name)
    lines = [
        f"# Calibration of the {result.rig} twin: {name}",
        "",
        f"- targets: {targets.source}",
        f"- protocol: `{result.protocol}`",
        f"- objective J: {result.j:.4f} ({result.j_stage}) after {result.evaluations} new "
        f"evaluations ({result.reused} re-used from the log), {result.wall_s:.0f} s wall, "
        f"{result.cpu_s:.0f} CPU-s in the evaluations, {result.budget_clock_s:.0f} s of the budget's clock",
        f"- verdict: {closing_line(result.verdicts)}",
        "",
        "## Parameters",
        "",
        "| unknown | value | near-best range | interval (± 2σ, landmarks) | unit |",
        "|---|---|---|---|---|",
    ]
    spread = result.identifiability.get("fine_spread") or result.identifiability.get("spread", {})
    ivals = (result.identifiability.get("intervals") or {}).get("unknowns", {})
    for k, v in result.values.items():
        s = spread.get(k)
        rng = f"{s['min']:.4g} … {s['max']:.4g}" if s else "fixed"
        unit = s["unit"] if s else ""
        iv = ivals.get(k)
        ci = "" if iv is None else f"{iv['lo']:.4g} … {iv['hi']:.4g}" + ("" if iv["pinned"] else " (not pinned)")
        if iv is not None and iv.get("given"):
            ci += f" (with {', '.join(iv['given'])} as found)"
        lines.append(f"| {k} | {v:.5g} | {rng} | {ci} | {unit} |")
    for k, v in result.extras.items():
        lines.append(f"| {k} (derived) | {v:.5g} | | | |" if isinstance(v, float) else f"| {k} | {v} | | | |")
    method = (result.identifiability.get("intervals") or {}).get("method")
    if method:
        lines += ["", f"Intervals: {method}; not pinned: the landmarks leave the unknown anywhere in its bounds."]
    lines += ["", "## Targets vs twin", "", *_targets_table(result, targets)]
    dirs = result.identifiability.get("directions")
    if dirs:
        lines += ["", "## Identifiability", "", result.identifiability.get("method", ""), ""]
        for d in dirs:
            lines.append(f"- {json.dumps({k: v for k, v in d.items()}, default=json_default)}")
    lines += [
        "",
        "## Objective per generation",
        "",
        "| gen | stage | best | median | points | elapsed s |",
        "|---|---|---|---|---|---|",
    ]
    for h in result.history:
        lines.append(
            f"| {h['generation']} | {h['stage']} | {h['best']:.4f} | {h['median']:.4f} | {h['n']} | "
            f"{h['elapsed_s']:.0f} |"
        )
    lines += ["", f"![maps]({name}_maps.png)", "", f"![objective]({name}_objective.png)", ""]
    path = out_dir / f"{name}_report.md"
    path.write_text("\n".join(lines))
    return path


def _targets_table(result: Result, targets: Targets) -> list[str]:
    """One row per target with its tolerance and verdict (:mod:`.verdict`); a rig without checks: the summary."""
    if not result.verdicts:
        rows = ["| quantity | target | twin |", "|---|---|---|"]
        for k, v in result.summary.items():
            tv = targets.scalars.get(k)
            if not (isinstance(v, dict) or isinstance(tv, dict)):
                rows.append(f"| {k} | {tv} | {v} |")
        return rows
    rows = [
        "| target | wanted | twin | near-best twins | over noise seeds | tolerance | verdict | limited by |",
        "|---|---|---|---|---|---|---|---|",
    ]
    spread = result.identifiability.get("landmark_spread", {})
    for v in result.verdicts:
        sp = spread.get(v.target)
        near = f"{sp['min']:.4g} … {sp['max']:.4g} ({sp['n']})" if sp else ""
        rows.append(
            f"| {v.target} | {v.wanted_text()} | {v.twin_text()} | {near} | {v.spread_text()} | {v.tolerance_text} | "
            f"{'met' if v.met else '**missed**'} | {v.limited_by or ''} |"
        )
    return rows


def _label_level(row: dict) -> float:
    """A step's level from its label as the table's transitions read it (an irregular step's from its contacts
    per cycle): not moved by the measured ratio or pulled toward continuous by the in-contact fraction as the
    objective's level is (the figure must agree with the table)."""
    label = str(row.get("regime", ""))
    ratio = float(row.get("contacts_per_cycle", math.nan)) if label == IRREGULAR else math.nan
    return regime_level(label, ratio)


def _figures(result: Result, meas: pd.DataFrame, twin: pd.DataFrame, out_dir: Path, name: str) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 3.2), layout="constrained")
    ax = fig.add_subplot()
    stages = (
        ("prior line", "v"),
        ("landmark step", "P"),
        ("coarse", "o"),
        ("fine", "s"),
        ("bracket", "^"),
        ("verify", "D"),
    )
    for stage, marker in stages:  # every stage the history records, so no generation is left out
        h = [x for x in result.history if x["stage"] == stage]
        if h:
            ax.plot([x["generation"] for x in h], [x["best"] for x in h], marker + "-", label=f"{stage} best")
            ax.plot(
                [x["generation"] for x in h],
                [x["median"] for x in h],
                marker,
                alpha=0.4,
                mfc="none",
                label=f"{stage} median",
            )
    ax.set_yscale("symlog", linthresh=0.01)
    ax.set_xlabel("generation")
    ax.set_ylabel("objective J (each stage on its own maps)")
    fig.legend(fontsize=7, loc="outside right upper")  # beside the axes, never over the data
    fig.savefig(out_dir / f"{name}_objective.png", dpi=110)

    fig = Figure(figsize=(8, 3.6), layout="constrained")
    ax = fig.add_subplot()
    if "regime" in meas and meas["regime"].astype(str).ne("").any():
        ax.plot(
            meas["frequency_hz"],
            [_label_level(r) for r in meas.to_dict("records")],
            "o",
            ms=7,
            mfc="none",
            label="measured / target",
        )
        ax.plot(
            twin["frequency_hz"],
            [_label_level(r) for r in twin.to_dict("records")],
            "x",
            ms=6,
            label="calibrated twin",
        )
        ax.set_yticks(
            [CONTINUOUS_LEVEL, -0.5, 0, 1, math.log2(3), 2, 3], ["continuous", "2+", "1", "1/2", "1/3", "1/4", "none"]
        )
        ax.set_ylabel("regime (contacts per cycle)")
    else:  # e.g. the walker: plot the numeric targets the rig names
        for col in [c for c in meas.columns if c not in ("frequency_hz", "regime")][:1]:
            ax.plot(meas["frequency_hz"], meas[col], "o", mfc="none", label=f"target {col}")
            if col in twin:
                ax.plot(twin["frequency_hz"], twin[col], "x-", label=f"twin {col}")
            ax.set_ylabel(col)
    ax.set_xlabel("drive frequency (Hz)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(out_dir / f"{name}_maps.png", dpi=110)
