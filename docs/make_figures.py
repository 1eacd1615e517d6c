"""Render the README's pictures with beambench itself: ``python docs/make_figures.py`` (about a minute).

1. Runs a short contact sweep on the sim (plate 1 mm below the foot, so it touches) with ``--rerun save``.
2. ``docs/img/live_view.png``: what the live view shows, drawn from that run's ``.rrd`` as read back with
   Rerun's own reader (markers in 3-D, plate forces in N, raw load-cell counts) — the viewer itself needs a GPU
   and a display, so this is a rendering of the recording, not a screenshot of the viewer.
3. ``docs/img/report_*.png``: figures of ``beambench analyze`` on that session.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
IMG = HERE / "img"
PROTOCOL = """
name: readme_demo
rig: contact
sweep: {frequencies: [6, 10, 18, 26, 33, 40]}
settle_s: 1.0
record_s: 2.0
amplitude_mm: 2.0
limits: {max_frequency_hz: 40}
sim: {model: prb3, params: paper, plate_gap_mm: 1.0, twist_deg: 90, noise: true, seed: 0}
"""


def _beambench(*args: str) -> str:
    res = subprocess.run([sys.executable, "-m", "beambench", *args], capture_output=True, text=True, check=True)
    return res.stdout.strip().splitlines()[-1]


def _columns(rrd: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """entity → (session time s, values) for every temporal entity of the recording."""
    import rerun.chunk as rc

    out: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for chunk in rc.RrdReader(rrd).stream():
        if chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        value_col = next((n for n in names if n.endswith((":scalars", ":positions"))), None)
        if value_col is None or "session_time" not in names:
            continue
        t = np.asarray(batch.column("session_time").cast("int64").to_numpy(zero_copy_only=False)) * 1e-9
        values = np.array([np.asarray(v, float).ravel() for v in batch.column(value_col).to_pylist()])
        out.setdefault(chunk.entity_path, []).append((t, values))
    return {k: (np.concatenate([t for t, _ in v]), np.concatenate([x for _, x in v])) for k, v in out.items()}


def live_view_picture(rrd: Path, path: Path, t0: float, span: float = 0.3) -> None:
    from matplotlib.figure import Figure

    cols = _columns(rrd)
    fig = Figure(figsize=(11, 4.6), dpi=110, layout="constrained")
    grid = fig.add_gridspec(2, 2, width_ratios=[1.1, 1])
    ax3 = fig.add_subplot(grid[:, 0], projection="3d")
    for name, color in (("stage", "#2ca02c"), ("tip", "#1f77b4"), ("foot", "#d62728")):
        t, p = cols[f"/mocap/{name}"]
        sel = (t >= t0) & (t <= t0 + span)
        ax3.plot(p[sel, 0], p[sel, 1], p[sel, 2], ".", ms=2, color=color, label=name)
    ax3.set(xlabel="x (mm)", ylabel="y (mm)", zlabel="z (mm, up)", title="Markers (mm)")
    ax3.legend(loc="upper left")
    axf = fig.add_subplot(grid[0, 1])
    for name, color in (("normal", "#d62728"), ("tangential", "#1f77b4")):
        t, v = cols[f"/force/{name}"]
        sel = (t >= t0) & (t <= t0 + span)
        axf.plot(t[sel], v[sel, 0], lw=0.9, color=color, label=name)
    axf.set(ylabel="force (N)", title="Plate force (N)")
    axf.legend(loc="upper right", frameon=False)
    axc = fig.add_subplot(grid[1, 1], sharex=axf)
    for k in range(4):
        t, v = cols[f"/loadcell/lc{k}"]
        sel = (t >= t0) & (t <= t0 + span)
        axc.plot(t[sel], v[sel, 0], lw=0.8, label=f"lc{k}")
    axc.set(xlabel="session time (s)", ylabel="counts", title="Load cells (raw counts)")
    axc.legend(loc="upper right", ncol=4, frameon=False, fontsize=8)
    fig.suptitle("Live view content (Rerun recording of `beambench run --rerun save`, read back and drawn)")
    fig.savefig(path)


def main() -> None:
    IMG.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmpdir = Path(tmp)
        proto = tmpdir / "readme_demo.yaml"
        proto.write_text(PROTOCOL)
        session = Path(_beambench("run", str(proto), "--rerun", "save", "--out", str(tmpdir), "--name", "demo"))
        live_view_picture(session.with_suffix(".rrd"), IMG / "live_view.png", t0=16.0)
        index = Path(_beambench("analyze", str(session), "--out", str(tmpdir / "report"), "--no-write", "-q"))
        for name in ("trajectories", "forces", "contact_frequency"):
            shutil.copy(index.parent / f"{name}.png", IMG / f"report_{name}.png")
    print(f"wrote {IMG}")


if __name__ == "__main__":
    main()
