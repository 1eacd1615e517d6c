"""Does any point of the contact twin's physical box meet the paper's map? A search dense enough to say. One command:

    nice -n 10 python benchmarks/bench_contact_search.py --points 1024 --jobs 2      # resumable: rerun to continue
    python benchmarks/bench_contact_search.py --validate 6 --jobs 2                  # the screen against the protocol
    python benchmarks/bench_contact_search.py --points 1024 --scheduler tcp://HOST:8786   # on a Dask cluster

The box: every bounded number of the shipped twin's beam and contact rig (``sim_backend/rod_physical.yaml``'s
``bounds:`` with a ``beam.`` or ``rig.`` key), uniform over its range, plus two model options, each on for half
the points (a Sobol dimension switches it): material damping with a frequency-independent loss factor
(``beam.loss_factor``, :mod:`beambench.sim.models.hysteretic`) instead of the stiffness-proportional β, and the
load frame as a rigid body of bounded inertia (``rig.frame_gyration``). The contact's damping ratio is varied at a
fixed stiffness (its time constant scaled by 1/ζ). h' is uniform over its bounds too, so the sample covers the
box as it is: where the foot hangs clear of the plate at rest (sag < h'), the points say so.

A point whose foot hangs more than 1.5 mm above the plate at rest (:data:`CLEAR_M`) keeps its sag and release
deflection but is not screened (``screened`` 0; ``--screen-all`` screens it): it cannot hold the continuous band,
and the largest vertical motion seen at 26–38 Hz is about half that clearance. Each other point is the cheap screen (:func:`beambench.sim.scenes.contact_screen.screen_map`: 16 stepped frequencies,
0.4 + 0.6 s, noise off, at the point's converged timestep; a few CPU-seconds) and its release test's loaded
deflection (200 g at the tip, the static equilibrium). Per point: continuous band, lowest ½, lowest ⅓, tangential
sign at 26 and 40 Hz, lift-off height at 26 and 38 Hz, the release deflection, the static sag and the preload.
A row is appended to the CSV (``--csv``, default ``docs/data/contact_search.csv``) as each point finishes, so a
killed run loses only the points in flight and a rerun continues with the next Sobol indices.

``--validate N`` runs N points (the shipped one, the CSV's best by landmarks met and as many drawn at random among
those whose foot touches the plate) through the full protocol
(``protocols/contact_sweep.yaml``: 1–40 Hz, 2 + 5 s, stepped, noise off, same timestep) and counts the landmarks on
which the screen agrees (``contact_search_validation.csv`` beside the CSV).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

PROTOCOL = ROOT / "protocols" / "contact_sweep.yaml"
CSV = ROOT / "docs" / "data" / "contact_search.csv"
TARGETS = {"continuous_below_hz": (18.0, 2.0), "half_at_hz": (26.0, 2.0), "third_at_hz": (38.0, 2.0)}
SIGNS = {26.0: -1, 40.0: 1}  # calibration/paper_contact_targets.yaml
LANDMARKS = (*TARGETS, *(f"sign_{hz:g}" for hz in SIGNS))
LIFTOFF_HZ = (26.0, 38.0)
# a foot hanging this far (m) above the plate at rest is not screened: it cannot meet the continuous band, and to touch
# at all its vertical motion would need an amplitude twice the largest the earlier search saw (0.8 mm, with the corner
# 30 mm off the tip, docs/contact-twin.md); --screen-all screens it anyway
CLEAR_M = 1.5e-3
RELEASE_FIT_M = 0.0131  # the paper's PRB3 release fit: 200 g at the tip (docs/contact-twin.md)
OPTIONS = {"beam.loss_factor": "damping", "rig.frame_gyration": "frame"}  # option key -> its switch's column
SOBOL_BITS = 14  # the sequence the indices index: 16384 points
CODE = {"continuous": "C", "1/2": "h", "1/3": "t", "1/4": "q", "irregular": ".", "none": "-"}


def box() -> dict:
    """The bounded numbers of the beam and the contact rig (the walker's do not touch the contact map)."""
    from beambench.sim.models.params import load_params

    bounds = load_params("physical", "rod").bounds
    return {k: b for k, b in bounds.items() if k.startswith(("beam.", "rig."))}


def point_values(index: int) -> dict[str, float]:
    """Sobol point ``index`` of the box (scrambled, seed 0): every bounded number, the two options' switches
    (``damping``: 1 = loss factor, 0 = β; ``frame``: 1 = rigid frame with gyration, 0 = spread)."""
    from scipy.stats import qmc

    b = box()
    keys = sorted(b)
    seq = qmc.Sobol(len(keys) + len(OPTIONS), scramble=True, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        if index:
            seq.fast_forward(index)
        u = seq.random(1)[0]
    values = {k: b[k].min + float(x) * (b[k].max - b[k].min) for k, x in zip(keys, u)}
    for (key, switch), x in zip(OPTIONS.items(), u[len(keys) :]):
        values[switch] = float(x >= 0.5)
        if not values[switch]:
            values[key] = 0.0
    return values


def release_deflection(twin) -> float:
    """The release test's loaded tip deflection (m): 200 g at the tip, the static equilibrium against rest."""
    from beambench.sim.models.registry import make_beam_model
    from beambench.sim.scenes.release import G, release_batch, release_models

    models = release_models([make_beam_model(twin.model, twin.params)], twist_deg=90.0)
    rb = release_batch(models, 0.2 * G, 0.01, with_rest=True, nthread=1)
    return float(np.linalg.norm(rb.loaded[0].mean(axis=0) - rb.rest[0].mean(axis=0)))


def landmarks(table) -> dict:
    """A map's landmarks, signs and lift-off heights (the screen's or the protocol's table)."""
    from beambench.sim.scenes.contact_regimes import transitions

    f = table["frequency_hz"].to_numpy(float)
    regimes = [str(r) for r in table["regime"]]
    out: dict = dict(transitions(f, regimes))
    for hz in SIGNS:
        out[f"sign_{hz:g}"] = int(table["tangential_sign"].iloc[int(np.argmin(abs(f - hz)))])
    if "liftoff_mm" in table:
        for hz in LIFTOFF_HZ:
            out[f"liftoff_{hz:g}_mm"] = float(table["liftoff_mm"].iloc[int(np.argmin(abs(f - hz)))])
    out["map"] = "".join(CODE.get(r, r[0]) for r in regimes)
    return out


def met(r: dict) -> dict[str, bool]:
    """Which of the paper's landmarks a row meets."""
    out = {k: _num(r[k]) is not None and abs(_num(r[k]) - hz) <= tol for k, (hz, tol) in TARGETS.items()}
    return out | {f"sign_{hz:g}": int(float(r[f"sign_{hz:g}"])) == s for hz, s in SIGNS.items()}


def _num(x) -> float | None:
    if x is None or x == "" or (isinstance(x, float) and math.isnan(x)):
        return None
    return float(x)


def screen_point(index: int, screen_all: bool = False) -> dict:
    """One Sobol point's screen (in a worker): values, sag, preload, release deflection, landmarks, CPU. A point
    whose foot hangs more than :data:`CLEAR_M` above the plate at rest gets ``screened`` 0 and meets nothing."""
    from beambench.sim.scenes.contact_regimes import static_sag
    from beambench.sim.scenes.contact_screen import point_twin, screen_map

    c0 = time.process_time()
    values = point_values(index)
    twin = point_twin(values)
    beam, rig = twin.build()
    sag = static_sag(beam, rig)
    row: dict = {"index": index, **values}
    row |= {"sag_mm": sag * 1e3, "preload_mm": (sag - rig.plate_gap) * 1e3}
    row["release_mm"] = release_deflection(twin) * 1e3
    row["screened"] = int(screen_all or sag - rig.plate_gap >= -CLEAR_M)
    if row["screened"]:
        row |= landmarks(screen_map(twin))
    else:
        row |= {k: None for k in TARGETS} | {f"sign_{hz:g}": 0 for hz in SIGNS} | {"map": ""}
    m = met(row)
    row |= {f"met_{k}": int(v) for k, v in m.items()} | {"met": sum(m.values())}
    row["cpu_s"] = time.process_time() - c0
    return row


def screen_task(task: tuple[list[int], bool]) -> list[dict]:
    indices, screen_all = task
    return [screen_point(i, screen_all) for i in indices]


def columns() -> list[str]:
    lift = [f"liftoff_{hz:g}_mm" for hz in LIFTOFF_HZ]
    return (
        [
            "index",
            *sorted(box()),
            *OPTIONS.values(),
            "sag_mm",
            "preload_mm",
            "release_mm",
            "screened",
            *LANDMARKS,
            *lift,
            "map",
        ]
        + [f"met_{k}" for k in LANDMARKS]
        + ["met", "cpu_s"]
    )


def read_rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def search(n: int, csv_path: Path, jobs: int, scheduler: str | None, per_task: int, screen_all: bool) -> None:
    """Screen Sobol indices 0…n−1 not yet in ``csv_path``, appending each finished point's row."""
    from beambench.studies.executor import chunks, make_executor, run_tasks

    write_shipped(csv_path)
    done = {int(r["index"]) for r in read_rows(csv_path)}
    todo = [i for i in range(n) if i not in done]
    print(f"{len(done)} points in {csv_path}; {len(todo)} to screen", flush=True)
    if not todo:
        return
    csv_path.parent.mkdir(parents=True, exist_ok=True)
    cols = columns()
    fresh = not csv_path.exists() or not done
    w0, cpu, count = time.perf_counter(), 0.0, 0
    with csv_path.open("a" if not fresh else "w", newline="") as fh:
        writer = csv.DictWriter(fh, cols, extrasaction="ignore")
        if fresh:
            writer.writeheader()

        def on_done(_task: tuple[list[int], bool], rows: list[dict]) -> None:
            nonlocal cpu, count
            for r in rows:
                writer.writerow({k: _fmt(r.get(k)) for k in cols})
                cpu += r["cpu_s"]
                count += 1
            fh.flush()
            r = rows[-1]
            print(
                f"[{len(done) + count}/{n} {time.perf_counter() - w0:6.0f} s, {cpu / count:4.1f} CPU-s/point] "
                f"#{r['index']} met {r['met']}/5 preload {r['preload_mm']:+.2f} {r['map']}",
                flush=True,
            )

        with make_executor(jobs, scheduler) as pool:
            run_tasks(pool.executor, screen_task, [(c, screen_all) for c in chunks(todo, per_task)], on_done)


def write_shipped(csv_path: Path) -> None:
    """The shipped point's screen map and landmarks met (the figure's first row), beside the CSV, unless there."""
    dest = csv_path.with_name(csv_path.stem + "_shipped.txt")
    if not dest.exists():
        csv_path.parent.mkdir(parents=True, exist_ok=True)
        r = screen_point_values({})
        dest.write_text(f"{r['map']} {sum(met(r).values())}\n")


def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return str(v)


def full_point(values: dict[str, float]) -> dict:
    """The full protocol's landmarks of a point (in a worker): stepped 1–40 Hz, 2 + 5 s, noise off."""
    from beambench.acquisition.protocol.schema import load_protocol
    from beambench.sim.scenes.contact_regimes import stepped_regime_map
    from beambench.sim.scenes.contact_screen import converged_dt, point_twin
    from beambench.sim.settings import SimSettings

    protocol, _ = load_protocol(PROTOCOL)
    twin = point_twin(values)
    dt = converged_dt(twin.build()[1])
    sim = SimSettings(2.0, 5.0, protocol.sim.twist_deg, protocol.amplitude_mm * 1e-3, "implicitfast", dt)
    c0 = time.process_time()
    out = landmarks(stepped_regime_map(list(protocol.sweep.values()), sim, twin))
    return out | {"cpu_s": time.process_time() - c0}


def validate(n: int, csv_path: Path, jobs: int, scheduler: str | None) -> None:
    """The screen against the full protocol on the shipped point and the CSV's ``n − 1`` best."""
    from beambench.studies.executor import make_executor, run_tasks

    rows = read_rows(csv_path)
    ranked = sorted(rows, key=lambda r: (-int(r["met"]), int(r["index"])))
    top = ranked[: max(0, n - 1) - (n - 1) // 2]
    touching = [r for r in ranked[len(top) :] if r["map"].strip("-")]  # points whose foot meets the plate
    rng = np.random.default_rng(0)
    pick = rng.choice(len(touching), size=min(len(touching), (n - 1) // 2), replace=False) if touching else []
    best = top + [touching[int(i)] for i in sorted(pick)]
    keys = [*sorted(box()), *OPTIONS.values()]
    points = [("shipped", {})] + [(f"#{r['index']}", {k: float(r[k]) for k in keys}) for r in best]
    shipped_screen = screen_point_values({})
    screens = {"shipped": shipped_screen} | {f"#{r['index']}": r for r in best}
    with make_executor(jobs, scheduler) as pool:
        fulls = run_tasks(pool.executor, full_point, [v for _, v in points])
    out_rows = []
    for (label, _), full in zip(points, fulls):
        scr = screens[label]
        ms, mf = met(scr), met(full)
        agree = {k: _agrees(k, scr, full) for k in LANDMARKS}
        out_rows.append(
            {"point": label}
            | {f"screen_{k}": _fmt(_num(scr[k])) for k in LANDMARKS}
            | {f"full_{k}": _fmt(_num(full[k])) for k in LANDMARKS}
            | {"screen_met": sum(ms.values()), "full_met": sum(mf.values()), "agree": sum(agree.values())}
            | {"full_map": full["map"], "full_cpu_s": f"{full['cpu_s']:.1f}"}
        )
        print(
            f"{label:10s} screen met {sum(ms.values())}/5, full {sum(mf.values())}/5; agree on "
            f"{sum(agree.values())}/5 landmarks; full map {full['map']}",
            flush=True,
        )
    dest = csv_path.with_name("contact_search_validation.csv")
    with dest.open("w", newline="") as fh:
        w = csv.DictWriter(fh, list(out_rows[0]))
        w.writeheader()
        w.writerows(out_rows)
    print(f"written {dest}")


def screen_point_values(values: dict[str, float]) -> dict:
    """The screen's landmarks at explicit ``values`` (the shipped point: ``{}``)."""
    from beambench.sim.scenes.contact_screen import point_twin, screen_map

    return landmarks(screen_map(point_twin(values)))


def _agrees(key: str, screen: dict, full: dict) -> bool:
    """A landmark agrees when both miss it or both give it within 2 Hz (a sign: the same sign)."""
    if key.startswith("sign_"):
        return int(float(screen[key])) == int(float(full[key]))
    a, b = _num(screen[key]), _num(full[key])
    return (a is None and b is None) or (a is not None and b is not None and abs(a - b) <= 2.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1024, help="Sobol indices 0…N−1 (those already in the CSV kept)")
    ap.add_argument("--jobs", type=int, default=2, help="local worker processes")
    ap.add_argument("--scheduler", default=None, help="a Dask scheduler address (tcp://HOST:8786)")
    ap.add_argument("--per-task", type=int, default=2, help="points per submitted task")
    ap.add_argument("--csv", type=Path, default=CSV)
    ap.add_argument("--validate", type=int, default=0, help="run N points through the full protocol instead")
    ap.add_argument("--screen-all", action="store_true", help="screen points whose foot hangs clear of the plate too")
    args = ap.parse_args()
    if args.points > 2**SOBOL_BITS:
        raise SystemExit(f"--points {args.points}: at most {2**SOBOL_BITS}")
    if args.validate:
        validate(args.validate, args.csv, args.jobs, args.scheduler)
    else:
        search(args.points, args.csv, args.jobs, args.scheduler, args.per_task, args.screen_all)


if __name__ == "__main__":
    main()
