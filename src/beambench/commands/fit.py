"""``beambench fit SESSION.h5``: identify the beam model from a release-test session (:mod:`beambench.studies.fit.release`)."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import typer

from beambench.commands import command_of, fail


@dataclass(frozen=True)
class FitArgs:
    """``beambench fit``'s argument and options as one value (the command's signature is made of these fields)."""

    session: Path = typer.Argument(
        ...,
        metavar="SESSION",
        help="A release-test session (.h5), e.g. from `beambench run protocols/release_test.yaml`.",
    )
    out: Path = typer.Option(
        None,
        "--out",
        "-o",
        help="Folder for the figure and the JSON report (default: <session>_fit beside the session).",
    )
    model: str = typer.Option(
        "prb3", "--model", "-m", help="prb3, rod (= rod10), rodN, or a comma list such as prb3,rod10 to fit several."
    )
    free_l1: bool = typer.Option(
        False, "--free-l1", help="PRB3: fit l1 too (default l1 = 0, as the paper settled on; l3 = 50 mm − l1 − l2)."
    )
    name: str = typer.Option(
        None,
        "--name",
        "-n",
        metavar="NAME",
        help="Name of the parameter set written (<model>_<name>.yaml; select it with `sim.params: <name>`). "
        "Default: the session name.",
    )
    params_dir: Path | None = typer.Option(
        None,
        "--params-dir",
        metavar="DIR",
        help="Where to write the parameter set (default: sim_backend/ in the per-user folder, where `sim.params` "
        "finds it; see docs/commands.md, 'Where files go').",
    )
    no_write: bool = typer.Option(False, "--no-write", help="Do not write a parameter set or /processing.")
    method: str = typer.Option(
        "sysid",
        "--method",
        help="sysid: screen the bounds in one batch for a start, then mujoco.sysid least squares (default); "
        "de: differential evolution only (the paper's optimizer); de+sysid: DE as a global start for a bad "
        "initial guess, then the least squares. Every method reports 95 % intervals (mujoco.sysid).",
    )
    max_iters: int = typer.Option(40, "--max-iters", help="Least-squares (Levenberg–Marquardt) iterations at most.")
    popsize: int = typer.Option(12, "--popsize", help="Differential-evolution population per variable (de, de+sysid).")
    maxiter: int = typer.Option(60, "--maxiter", help="Maximum DE generations (de, de+sysid).")
    seed: int = typer.Option(0, "--seed", help="Random seed of the screen and the DE.")
    threads: int = typer.Option(0, "--threads", help="Simulation threads (0: all cores).")
    timestep: float = typer.Option(2e-4, "--timestep", help="Simulation timestep of the fit (s).")
    register: bool = typer.Option(
        None,
        "--register/--no-register",
        help="Map the mocap frame onto the model's "
        "(clamp at the origin, beam along +y, z up) from the rest pose. Default: on for "
        "sessions not made by the sim.",
    )


def fit(args: FitArgs) -> None:
    """Fit the PRB3 model (k, b, l2; optionally l1) and/or the segmented rod (E, damping) to a release test.

    Minimises the paper's objective — RMS distance between measured and simulated tip markers over all
    samples — as a least-squares problem with MuJoCo's mujoco.sysid (Levenberg–Marquardt, each Jacobian one
    batched rollout), started from the best of one batch screening the parameters' physical bounds; --method de
    runs the paper's differential evolution instead. Prints each fitted value ± its 95 % confidence interval
    (mujoco.sysid.calculate_intervals), the final error (mm), the rollouts and the wall time; draws measured vs
    fitted tip paths, writes a JSON report, and saves each fit (intervals in its source and fit notes) as a
    named parameter set in the per-user folder that protocols select with `sim.params`.

    Measured (benchmarks/bench_fit_sysid.py: synthetic release tests, 0.3 mm noise, 0.35 s, 2 threads,
    median of 3): rod5 sysid 4.0 s / 54 rollouts vs de 30.5 s / 533; PRB3 sysid 1.3 s / 39 vs de 27.1 s / 1158;
    both reach the noise floor (0.50 mm RMS), intervals E ±0.13 %, β ±1.0 %, k ±0.9 %, b ±2.4 %, l2 ±1.8 %.
    Intervals count marker noise, not model error.
    """
    from rich.console import Console

    from beambench.common.console import stderr_console
    from beambench.studies.fit.figure import plot_fit
    from beambench.studies.fit.release import FitError, load_release_session

    models = _checked(args)
    session = args.session
    name = args.name or re.sub(r"[^A-Za-z0-9_.-]", "_", session.stem)
    out = args.out or session.with_name(session.stem + "_fit")
    console = stderr_console()
    try:
        data = load_release_session(session, register=args.register)
    except FitError as exc:
        fail(str(exc))
    _check_outputs(args, models, name, out)
    try:  # after the session is read: a refused session leaves no folder behind
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        fail(f"--out = {str(out)!r}: cannot create ({exc.strerror or exc})")
    results = [_fit_one(data, m, args, console) for m in models]
    _print_results(results, data, Console())
    fig = plot_fit(results, out / f"fit_{session.stem}.png", title=f"Release test {session.name}: measured vs fitted")
    _write_outputs(args, results, name, out, fig, console)


def _checked(args: FitArgs) -> list[str]:
    """The models to fit; one line and exit 2 for bad options."""
    from beambench.common.names import check_name
    from beambench.sim.models.families import FAMILIES
    from beambench.sim.models.registry import UnknownModelError, canonical_model, is_rod

    models = [m.strip() for m in args.model.split(",") if m.strip()]
    if not models:
        fail(f"--model = {args.model[:40]!r}: name a model: prb3, rod, or rodN (e.g. rod10)")
    if args.name is not None:
        try:  # the parameter set is <model>_<name>.yaml in its folder: one path component
            check_name(args.name, "--name")
        except ValueError as exc:
            fail(str(exc))
    for m in models:
        try:
            canonical_model(m)
        except UnknownModelError:
            fail(f"--model = {m[:40]!r}: prb3, rod, or rodN (e.g. rod10, rod5g)")
    if args.free_l1 and all(is_rod(m) for m in models):
        joint_springs = " or ".join(f.name for f in FAMILIES.values() if not f.segmented)
        fail(f"--free-l1 applies to a model on joint springs ({joint_springs})")
    if not args.session.is_file():
        fail(f"{args.session}: no such session file")
    from beambench.studies.fit.release import METHODS

    if args.method not in METHODS:
        fail(f"--method = {args.method[:40]!r}: one of {', '.join(METHODS)}")
    for opt, value, ok in (
        ("--max-iters", args.max_iters, args.max_iters >= 1),
        ("--popsize", args.popsize, args.popsize >= 4),
        ("--maxiter", args.maxiter, args.maxiter >= 1),
        ("--threads", args.threads, args.threads >= 0),
        ("--timestep", args.timestep, 0 < args.timestep <= 2e-3),
    ):
        if not ok:
            fail(f"{opt} = {value}: out of range")
    return models


def _check_outputs(args: FitArgs, models: list[str], name: str, out: Path) -> None:
    """Every place fit writes, before the fit: the output folder and the parameter sets (never through a link,
    into a folder that takes files); one line and exit 2."""
    from beambench.common.outputs import output_file_problem, output_folder_problem
    from beambench.common.resources import user_dir
    from beambench.sim.models.registry import canonical_model, model_family

    stem = args.session.stem
    problem = output_folder_problem(out, (f"fit_{stem}.png", f"fit_{stem}.json"))
    if problem:
        fail(f"{problem}: the fit's folder (give another with --out)")
    if args.no_write:
        return
    directory = args.params_dir or user_dir("sim_backend")
    for m in models:
        problem = output_file_problem(directory / f"{model_family(canonical_model(m))}_{name}.yaml")
        if problem:
            fail(f"{problem}: the parameter set (give another --name or --params-dir)")


def _fit_one(data: Any, m: str, args: FitArgs, console: Any) -> Any:
    """One model's fit, with a progress bar."""
    from rich.progress import BarColumn, TextColumn, TimeElapsedColumn

    from beambench.common.console import LogProgress
    from beambench.sim.models.registry import is_rod
    from beambench.studies.fit.release import FitError, FitOptions, fit_release

    options = FitOptions(
        method=args.method,
        max_iters=args.max_iters,
        free_l1=args.free_l1 and not is_rod(m),
        popsize=args.popsize,
        maxiter=args.maxiter,
        seed=args.seed,
        timestep=args.timestep,
        nthread=args.threads or None,
    )
    with LogProgress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("step {task.completed:.0f}"),
        TextColumn("{task.fields[err]}"),
        TimeElapsedColumn(),
        console=console,
        transient=True,
    ) as prog:
        total = args.max_iters + (args.maxiter if args.method != "sysid" else 0)
        task = prog.add_task(f"fitting {m} ({args.method})", total=total, err="")

        def progress(gen: int, best: float) -> None:
            prog.update(task, completed=gen, err=f"best RMS {best * 1e3:.3f} mm")

        try:
            return fit_release(data, m, options, progress=progress)
        except FitError as exc:
            fail(str(exc))


def _write_outputs(args: FitArgs, results: list, name: str, out: Path, fig: Path, console: Any) -> None:
    """The parameter sets (and /processing), the JSON report; their paths on stdout."""
    from beambench.common.resources import user_dir
    from beambench.studies.fit.release import write_param_set

    session = args.session
    report = {"session": str(session), "results": [r.summary() for r in results], "figure": str(fig)}
    written: list[Path] = []
    if not args.no_write:
        directory = args.params_dir or user_dir("sim_backend")
        for r in results:
            try:
                path = write_param_set(r, name, directory, source=f"beambench fit of {session.name} ({r.model})")
            except OSError as exc:
                fail(f"cannot write the parameter set to {directory} ({exc.strerror or exc})")
            written.append(path)
            _write_processing(session, r, console)
    report["param_sets"] = [str(p) for p in written]
    rep = out / f"fit_{session.stem}.json"
    rep.write_text(json.dumps(report, indent=2, default=float))
    typer.echo(f"figure: {fig}")
    typer.echo(f"report: {rep}")
    for p in written:
        found_by_name = p.parent.resolve() == user_dir("sim_backend").resolve()
        typer.echo(f"parameter set: {p}  (select with sim.params: {name if found_by_name else p})")


def _print_results(results, data, console) -> None:
    from rich.table import Table

    from beambench.studies.fit.release import PAPER_MAE_MM, value_with_interval
    from beambench.studies.fit.sysid import UNITS

    conf = f"{results[0].confidence:.0%}" if results else "95%"
    # truth and error: only where the session's own twin is the fitted model (a sim session of it); else no columns
    known = any(r.truth.get("model") == r.model for r in results)
    made_by = next((str(r.truth["model"]) for r in results if r.truth.get("model")), None)
    truth_note = (
        "error: fitted vs the generating model (sim sessions)"
        if known
        else f"no truth column: this session's twin is {made_by}, not the fitted model"
        if made_by
        else "no truth column: a measured session"
    )
    t = Table(
        title=f"Release-test fit ({len(data.t)} samples × {len(data.names)} tip markers)",
        caption=f"fitted ± the half-width of its {conf} confidence interval (mujoco.sysid.calculate_intervals: "
        f"noise only, not model error); {truth_note}; paper: {PAPER_MAE_MM} mm mean error against its rig",
    )
    cols = ("model", "parameter", f"fitted ± {conf} interval", *(("truth", "error") if known else ()))
    for col in cols:
        t.add_column(col, justify="right")

    def row(*cells: str, end_section: bool = False) -> None:
        t.add_row(*cells[: len(cols)], end_section=end_section)

    for r in results:
        same = r.truth.get("model") == r.model
        for key, v in r.values.items():
            sc, unit = UNITS.get(key, UNITS["l2"] if key in ("l1", "l3") else (1.0, ""))
            tv = r.truth.get(key) if same else None
            err = f"{(v / tv - 1) * 100:+.2f} %" if tv else ""
            shown = value_with_interval(r, key) if key in r.intervals else f"{v * sc:.5g} {unit}"
            row(r.model, key, shown, f"{tv * sc:.5g} {unit}" if tv is not None else "", err)
        if "release_shift_s" in r.intervals:
            row(r.model, "release shift", value_with_interval(r, "release_shift_s"), "", "")
        row(r.model, "RMS error (mm)", f"{r.rms_mm:.3f}", "", "")
        row(r.model, "mean marker error (mm)", f"{r.mae_mm:.3f}", "", "")
        row(r.model, "method", f"{r.method}: {r.nfev} rollouts, {r.generations} steps", "", "")
        row(r.model, "wall time (s)", f"{r.wall_s:.1f}", "", "", end_section=True)
    console.print(t)
    for r in results:
        for key, where in r.at_bounds.items():
            console.print(
                f"[yellow]{r.model}: {key} ended at its {where}: the release test asks for a value outside the "
                "physical range; its interval is not a confidence interval"
            )


def _write_processing(session: Path, result, console) -> None:
    import numpy as np

    from beambench.sinks.session_file.writer import write_processing

    nan = (float("nan"), float("nan"))
    bounds = np.array([result.intervals.get(k, nan) for k in result.values], float).reshape(-1, 2)
    table = {
        "parameter": np.array(list(result.values)),
        "value": np.array(list(result.values.values()), float),
        "lower": bounds[:, 0],  # the confidence interval (result.confidence), NaN where none
        "upper": bounds[:, 1],
    }
    try:
        write_processing(session, f"fit_{result.model}", table)
    except OSError as exc:
        console.print(f"[yellow]warning: could not write /processing/fit_{result.model} ({exc})")


def register(app: typer.Typer) -> None:
    app.command("fit")(command_of(FitArgs, fit))
