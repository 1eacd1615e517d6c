"""Cross-check of the MuJoCo beam models against an independent PyElastica Cosserat rod, one command:

    python benchmarks/bench_crosscheck.py --quick   # 3 frequencies, short windows (~1.5 min on 2 shared cores)
    python benchmarks/bench_crosscheck.py           # 5–45 Hz, 1 s settle + 0.5 s record, Cosserat n = 20 and 40

Free beam (stage x = A·sin 2πft, A = 2 mm, gravity), φ = 90° at each frequency and φ = 0 at one frequency:
tip RMS difference (mm) of every model against the Cosserat rod and against rod40, and the wall seconds per
simulated second of each model on one core (MuJoCo batches run with one thread; the Cosserat rod is a Python
loop over numba kernels). MuJoCo figures are medians of repeated runs where cheap (``--repeats``); the
Cosserat figure is the median over its frequencies (one run each). The machine is shared: read ratios.
Also the first natural frequencies of the untwisted beam: Euler–Bernoulli, Cosserat (free vibration) and rod40
(linearised modes).

Needs PyElastica (``pip install pyelastica``); the first run compiles its numba kernels (~20–40 s, cached).
Writes ``<out>/crosscheck.csv``, ``<out>/crosscheck_modes.csv`` and ``<out>/crosscheck_paths.png``; prints tables.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from beambench.sim.models import cosserat
from beambench.sim.models.registry import beam_model
from beambench.sim.scenes.free_beam import frequency_sweep
from beambench.sim.settings import SimSettings

SAMPLE_DT = 1e-4


def rms_mm(a: np.ndarray, b: np.ndarray) -> float:
    """Tip RMS distance (mm) of two [n, 3] paths."""
    return float(1e3 * np.sqrt(np.nanmean(np.sum((a - b) ** 2, axis=1))))


def on_grid(t_ref: np.ndarray, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Samples of ``x`` (at ``t``) at the times ``t_ref`` (which must be among ``t``)."""
    idx = np.searchsorted(t, t_ref - 1e-9)
    idx = np.clip(idx, 0, len(t) - 1)
    if np.max(np.abs(t[idx] - t_ref)) > 1e-9:
        raise ValueError("sample grids do not nest")
    return x[:, idx]


def mujoco_run(
    name: str, dt: float, freqs: list[float], twist: float, settle: float, record: float, repeats: int
) -> dict:
    """A MuJoCo sweep on one thread; wall per simulated second = median over ``repeats``."""
    walls, res = [], None
    for _ in range(repeats):
        settings = SimSettings(settle_s=settle, record_s=record, twist_deg=twist, timestep=dt, nthread=1)
        res = frequency_sweep(name, freqs, settings, sample_dt=max(dt, SAMPLE_DT))
        walls.append(res.wall_s)
    sim_s = len(freqs) * (settle + record)
    return {
        "label": f"{name} implicitfast {dt:g}",
        "model": name,
        "integrator": "implicitfast",
        "dt": dt,
        "t": res.t,
        "tip": res.tip,
        "wall_per_sim_s": statistics.median(walls) / sim_s,
        "ok": res.ok,
    }


def cosserat_run(n: int, dt: float, freqs: list[float], twist: float, settle: float, record: float) -> dict:
    p = cosserat.CosseratParams.from_beam(n_elements=n, timestep=dt)
    res = cosserat.frequency_sweep(freqs, twist, p, settle_s=settle, record_s=record, sample_dt=SAMPLE_DT)
    per = [w / res.info["simulated_per_run_s"] for w in res.info["wall_per_run_s"]]
    return {
        "label": f"cosserat{n} verlet {dt:g}",
        "model": f"cosserat{n}",
        "integrator": "PositionVerlet",
        "dt": dt,
        "t": res.t,
        "tip": res.tip,
        "wall_per_sim_s": statistics.median(per),
        "ok": res.ok,
        "alpha": p.alpha,
    }


def compare(runs: list[dict], freqs: list[float], twist: float) -> list[dict]:
    """Rows: each run's tip RMS difference (mm) vs the first run (Cosserat) and vs rod40, per frequency."""
    ref, rod40 = runs[0], next((r for r in runs if r["model"] == "rod40"), None)
    rows = []
    for r in runs:
        for i, f in enumerate(freqs):
            tip_c = on_grid(r["t"], ref["t"], ref["tip"])[i]
            vs40 = rms_mm(r["tip"][i], on_grid(r["t"], rod40["t"], rod40["tip"])[i]) if rod40 else float("nan")
            amp = float(1e3 * np.sqrt(np.nanmean(np.sum((tip_c - tip_c.mean(axis=0)) ** 2, axis=1))))
            rows.append(
                {
                    "twist_deg": twist,
                    "frequency_hz": f,
                    "model": r["model"],
                    "integrator": r["integrator"],
                    "dt": r["dt"],
                    "ok": bool(r["ok"][i]),
                    "rms_vs_cosserat_mm": rms_mm(r["tip"][i], tip_c),
                    "rms_vs_rod40_mm": vs40,
                    "cosserat_tip_rms_motion_mm": amp,
                    "wall_s_per_sim_s": r["wall_per_sim_s"],
                }
            )
    return rows


def modes_untwisted(n: int, dt: float) -> list[dict]:
    """First natural frequency about both axes: Euler–Bernoulli, Cosserat free vibration, rod40 modes."""
    import mujoco

    from beambench.sim.models.beam import add_beam
    from beambench.sim.models.rod import natural_frequencies

    p = cosserat.CosseratParams.from_beam(n_elements=n, timestep=dt)
    spec = mujoco.MjSpec()
    spec.option.gravity = [0, 0, 0]
    add_beam(spec.worldbody, beam_model("rod40"), 0.0)
    f40 = natural_frequencies(spec.compile())
    rows = []
    for axis in ("weak", "strong"):
        eb = p.rod.first_frequency(axis)
        fc = cosserat.first_frequency(p, axis)
        # rod40: the lowest mode of the family (weak bending is the 1st; strong bending the first above torsion
        # whose frequency is nearest the EB value)
        f_rod = float(f40[0]) if axis == "weak" else float(f40[np.argmin(np.abs(f40 - eb))])
        rows.append(
            {
                "axis": axis,
                "euler_bernoulli_hz": eb,
                f"cosserat{n}_hz": fc,
                "rod40_hz": f_rod,
                "cosserat_over_eb": fc / eb,
                "rod40_over_eb": f_rod / eb,
            }
        )
    return rows


def plot(runs90: list[dict], runs0: list[dict], freqs: list[float], f0: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [(runs90, i, f"φ = 90°, {f:g} Hz") for i, f in enumerate(freqs)] + [(runs0, 0, f"φ = 0°, {f0:g} Hz")]
    fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels), 3.6))
    styles = {
        "cosserat": {"lw": 3, "alpha": 0.45, "color": "k"},
        "rod40": {"lw": 1.2, "color": "C0"},
        "rod10": {"lw": 1, "ls": "--", "color": "C1"},
        "prb3": {"lw": 1, "ls": ":", "color": "C3"},
    }
    for ax, (runs, i, title) in zip(axes, panels):
        for r in runs:
            key = "cosserat" if r["model"].startswith("cosserat") else r["model"]
            st = styles.get(key, {}) if not (key == "cosserat" and r is not runs[0]) else {"lw": 1, "color": "0.5"}
            ax.plot(1e3 * r["tip"][i, :, 0], 1e3 * r["tip"][i, :, 2], label=r["label"], **st)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("tip x (mm)")
        ax.set_aspect("equal", adjustable="datalim")
    axes[0].set_ylabel("tip z (mm)")
    axes[0].legend(fontsize=7, loc="upper left")
    fig.suptitle("Steady tip paths (stage x = 2 mm sin 2πft): PyElastica Cosserat vs MuJoCo models", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="3 frequencies, 0.5 s settle + 0.25 s record, n = 20 only")
    ap.add_argument("--out", type=Path, default=ROOT / "bench_out", help="output directory (default bench_out/)")
    ap.add_argument("--repeats", type=int, default=3, help="timing repeats of the cheap MuJoCo runs (default 3)")
    args = ap.parse_args()
    try:
        import elastica  # noqa: F401
    except ImportError:
        print("bench_crosscheck: PyElastica is not installed (pip install pyelastica)", file=sys.stderr)
        raise SystemExit(2) from None
    if args.quick:
        freqs, settle, record, f0 = [5.0, 25.0, 45.0], 0.5, 0.25, 15.0
        cos_cfg, rod40_dt = [(20, 1e-5)], 5e-5
    else:
        freqs, settle, record, f0 = [5.0, 15.0, 25.0, 35.0, 45.0], 1.0, 0.5, 15.0
        cos_cfg, rod40_dt = [(20, 1e-5), (40, 5e-6)], 2e-5
    args.out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()

    t0 = time.perf_counter()
    cosserat.frequency_sweep(
        [f0], 0.0, cosserat.CosseratParams.from_beam(n_elements=4), settle_s=1e-3, record_s=1e-3, presettle_s=1e-3
    )  # compile (or load) the numba kernels once
    compile_s = time.perf_counter() - t0

    def ladder(freq_list: list[float], twist: float, cos: list[tuple[int, float]]) -> list[dict]:
        runs = [cosserat_run(n, dt, freq_list, twist, settle, record) for n, dt in cos]
        runs.append(mujoco_run("rod40", rod40_dt, freq_list, twist, settle, record, 1))
        runs.append(mujoco_run("rod10", 1e-4, freq_list, twist, settle, record, args.repeats))
        runs.append(mujoco_run("prb3", 1e-4, freq_list, twist, settle, record, args.repeats))
        return runs

    runs90 = ladder(freqs, 90.0, cos_cfg)
    runs0 = ladder([f0], 0.0, cos_cfg[:1])
    rows = compare(runs90, freqs, 90.0) + compare(runs0, [f0], 0.0)
    modes = modes_untwisted(*cos_cfg[0])

    csv_path, modes_path, png = (
        args.out / "crosscheck.csv",
        args.out / "crosscheck_modes.csv",
        args.out / "crosscheck_paths.png",
    )
    for path, data in ((csv_path, rows), (modes_path, modes)):
        with path.open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(data[0]))
            w.writeheader()
            w.writerows(data)
    plot(runs90, runs0, freqs, f0, png)

    from rich.console import Console
    from rich.table import Table

    con = Console()
    tab = Table(
        title=f"Tip RMS difference (mm) vs {runs90[0]['label']}  [{'quick' if args.quick else 'full'}: "
        f"settle {settle} s, record {record} s]"
    )
    tab.add_column("φ, f (Hz)")
    tab.add_column("tip motion rms (mm)", justify="right")
    for r in runs90[1:]:
        tab.add_column(r["label"], justify="right")
    for twist, flist in ((90.0, freqs), (0.0, [f0])):
        for f in flist:
            mot = [x for x in rows if x["twist_deg"] == twist and x["frequency_hz"] == f]
            cells = [f"{mot[0]['cosserat_tip_rms_motion_mm']:.2f}"]
            for r in runs90[1:]:
                hit = [
                    x for x in rows if x["twist_deg"] == twist and x["frequency_hz"] == f and x["model"] == r["model"]
                ]
                cells.append(f"{hit[0]['rms_vs_cosserat_mm']:.3f}" if hit else "—")
            tab.add_row(f"{twist:g}°, {f:g}", *cells)
    tab.add_row("wall s / sim s", "", *[f"{r['wall_per_sim_s']:.3f}" for r in runs90[1:]])
    con.print(tab)
    print("wall s per simulated s (1 core): " + ", ".join(f"{r['label']}: {r['wall_per_sim_s']:.3f}" for r in runs90))
    t2 = Table(title="rod10 / PRB3 vs rod40 (mm)")
    t2.add_column("φ, f (Hz)")
    for m in ("rod10", "prb3", *(r["model"] for r in runs90 if r["model"].startswith("cosserat"))):
        t2.add_column(m, justify="right")
    for twist, flist in ((90.0, freqs), (0.0, [f0])):
        for f in flist:
            cells = []
            for m in [c.header for c in t2.columns[1:]]:
                hit = [x for x in rows if x["twist_deg"] == twist and x["frequency_hz"] == f and x["model"] == m]
                cells.append(f"{hit[0]['rms_vs_rod40_mm']:.3f}" if hit else "—")
            t2.add_row(f"{twist:g}°, {f:g}", *cells)
    con.print(t2)
    t3 = Table(title="Untwisted first natural frequency (Hz)")
    for k in modes[0]:
        t3.add_column(k, justify="right")
    for m in modes:
        t3.add_row(*[v if isinstance(v, str) else f"{v:.4g}" for v in m.values()])
    con.print(t3)
    print(
        f"numba compile/load {compile_s:.1f} s; damping α = {runs90[0]['alpha']:.2f} 1/s; total "
        f"{time.perf_counter() - t_start:.0f} s; wrote {csv_path}, {modes_path}, {png}"
    )


if __name__ == "__main__":
    main()
