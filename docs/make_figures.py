"""Regenerate every picture in ``docs/img`` from the shipped defaults: ``python docs/make_figures.py``.

Each picture is made by beambench itself from shipped protocols run as a user would run them (sim backend,
shipped parameter sets): the contact sweep, the walker sweep and the walker's speed tracking, their reports
(``beambench analyze``), the real Rerun viewer's own screenshots (``beambench view --screenshot``, headless, needs
a Vulkan driver) and the README's notebook example. The contact chart is drawn from the table its benchmark
writes (``benchmarks/bench_contact_chart.py`` → ``sim_backend/contact_chart.csv``; its physics is not rerun
here). Every PNG carries, in a PNG text chunk, a hash of the shipped
files it was made from (the protocols and the parameter sets they name) and of the code that draws it (a report
figure's module and the ``beambench.analysis`` modules it imports; the notebook example's function);
``tests/test_docs_images.py`` recomputes the hashes and fails when a picture was made from other defaults or
other drawing code than those shipped.

``--only NAME[,NAME]`` remakes the named pictures only (their runs are still made).
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import importlib.util
import inspect
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
IMG = HERE / "img"
HASH_KEY = "beambench:inputs"
MADE_BY_KEY = "beambench:made-by"


@dataclass(frozen=True)
class Picture:
    """One documentation picture: the shipped protocols it is made from, and how."""

    protocols: tuple[str, ...]
    how: str
    data: tuple[str, ...] = ()  # results a benchmark wrote (repository paths): the picture is drawn from them


PICTURES: dict[str, Picture] = {
    "report_trajectories.png": Picture(("contact_sweep",), "beambench analyze: trajectories.png"),
    "report_forces.png": Picture(("contact_sweep",), "beambench analyze: forces.png"),
    "report_contact_frequency.png": Picture(("contact_sweep",), "beambench analyze: contact_frequency.png"),
    "report_walking_speed.png": Picture(("walker_sweep",), "beambench analyze: walking_speed.png"),
    "live_view_contact.png": Picture(("contact_sweep",), "beambench view --screenshot --at 145"),
    "live_view_walker.png": Picture(("walker_sweep",), "beambench view --screenshot --at 151.5"),
    "tracking.png": Picture(("walker_track",), "beambench analyze: tracking.png"),
    "notebook_step.png": Picture(("contact_sweep",), "the README's notebook example"),
    "contact_chart.png": Picture(
        (),
        "the contact scene's speed/accuracy chart from benchmarks/bench_contact_chart.py's table",
        # the table, and where its shipped default is read from (the protocol and its parameter set)
        ("sim_backend/contact_chart.csv", "protocols/contact_sweep.yaml", "sim_backend/rod_physical.yaml"),
    ),
    "contact_search.png": Picture(
        (),
        "the box search's CSV (benchmarks/bench_contact_search.py)",
        ("docs/data/contact_search.csv", "docs/data/contact_search_shipped.txt"),
    ),
}


def shipped_inputs(protocol: str) -> list[Path]:
    """The shipped files a run of ``protocol`` depends on: the protocol and the parameter set it names."""
    import yaml

    from beambench.sim.models.params import find_params
    from beambench.sim.models.registry import model_family

    path = ROOT / "protocols" / f"{protocol}.yaml"
    data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    sim = data.get("sim") or {}
    files = [path]
    model = str(sim.get("model", "prb3"))
    params = str(sim.get("params", "paper"))
    family = "prb3" if model == "auto" else model_family(model)
    found = find_params(params, family)
    if found is not None:
        files.append(ROOT / "sim_backend" / found.name)
    return files


DRAWING_PACKAGE = "beambench.analysis"  # a figure's imports followed into the hash: those inside this package


def _runtime_imports(path: Path) -> set[str]:
    """The ``beambench.analysis`` modules a source file imports when it runs (not those under ``TYPE_CHECKING``):
    ``from a.b import c`` names ``a.b.c`` where that is a module, else ``a.b``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = {
        id(n)
        for node in ast.walk(tree)
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
        for n in ast.walk(node)
    }
    out: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith(DRAWING_PACKAGE)}
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith(DRAWING_PACKAGE):
            module = node.module or ""
            out |= {f"{module}.{a.name}" if _is_module(f"{module}.{a.name}") else module for a in node.names}
    return out


def _is_module(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, AttributeError):  # a parent that is a module, not a package
        return False


def drawing_code(name: str) -> list[Path]:
    """The source files that draw picture ``name``: a report figure's module and, transitively, the
    ``beambench.analysis`` modules it imports; none for the others (the notebook's function is hashed apart)."""
    how = PICTURES[name].how
    if not how.startswith("beambench analyze: "):
        return []
    from beambench.analysis.figures import FIGURES

    key = how.removeprefix("beambench analyze: ").removesuffix(".png")
    todo, seen = [FIGURES[key].draw.__module__], set()
    while todo:
        mod = todo.pop()
        if mod in seen:
            continue
        seen.add(mod)
        spec = importlib.util.find_spec(mod)
        if spec is not None and spec.origin:
            todo += sorted(_runtime_imports(Path(spec.origin)) - seen)
    files = {importlib.util.find_spec(m).origin for m in seen}  # type: ignore[union-attr]
    return sorted(Path(f) for f in files if f)


def inputs_hash(name: str) -> str:
    """SHA-256 of the shipped files picture ``name`` is made from (their repository paths and bytes) and of the
    code that draws it."""
    digest = hashlib.sha256()
    files = sorted({f for p in PICTURES[name].protocols for f in shipped_inputs(p)} | data_files(name))
    for f in files:
        digest.update(str(f.relative_to(ROOT)).encode() + b"\0" + f.read_bytes() + b"\0")
    for f in drawing_code(name):
        digest.update(f"{f.parent.name}/{f.name}".encode() + b"\0" + f.read_bytes() + b"\0")  # installed anywhere
    if PICTURES[name].how == "the README's notebook example":
        digest.update(inspect.getsource(notebook_picture).encode())
    if name in DRAWN_FROM_DATA:  # drawn from a benchmark's table: the functions that draw it
        for fn in DRAWN_FROM_DATA[name]():
            digest.update(inspect.getsource(fn).encode())
    return digest.hexdigest()


def data_files(name: str) -> set[Path]:
    """The benchmark results picture ``name`` is drawn from."""
    return {ROOT / d for d in PICTURES[name].data}


def contact_search_picture(out: Path) -> None:
    """The box search's coverage and best points, from its CSV (the search is not re-run here)."""
    from beambench.sim.scenes.contact_screen import SCREEN_FREQUENCIES
    from beambench.studies.contact_search_figure import plot_contact_search

    csv, shipped_txt = (ROOT / d for d in PICTURES["contact_search.png"].data)
    code, met = shipped_txt.read_text().split()
    plot_contact_search(csv, out, SCREEN_FREQUENCIES, shipped=(code, int(met)))


def read_stamp(png: Path) -> str | None:
    """The inputs hash stored in ``png``, or None."""
    from PIL import Image

    with Image.open(png) as im:
        return im.text.get(HASH_KEY) if hasattr(im, "text") else None


def stamp(src: Path, name: str) -> None:
    """Copy ``src`` to ``docs/img/name`` with the inputs hash in a PNG text chunk."""
    from PIL import Image, PngImagePlugin

    info = PngImagePlugin.PngInfo()
    info.add_text(HASH_KEY, inputs_hash(name))
    info.add_text(MADE_BY_KEY, f"python docs/make_figures.py ({PICTURES[name].how})")
    with Image.open(src) as im:
        im.load()
        im.save(IMG / name, pnginfo=info, optimize=True)
    print(f"  {name}", file=sys.stderr)


def _beambench(*args: str) -> Path:
    """Run a beambench command; its last stdout line (a path)."""
    env = {**os.environ, "MUJOCO_GL": "disable"}
    res = subprocess.run([sys.executable, "-m", "beambench", *args], capture_output=True, text=True, env=env)
    if res.returncode != 0:
        raise SystemExit(f"beambench {' '.join(args)} failed ({res.returncode}):\n{res.stderr}")
    return Path(res.stdout.strip().splitlines()[-1])


def notebook_picture(session: Path, out: Path) -> None:
    """The README's notebook example: the last 0.3 s of step 25, stage drive and plate force."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from beambench.analysis import resample_session
    from beambench.sinks.hdf5 import read_session

    s = read_session(session)
    df = resample_session(s, 1000)
    one = df[df.step == 25].iloc[-300:]
    fig, ax = plt.subplots(2, sharex=True, figsize=(7, 4.2), layout="constrained")
    ax[0].plot(one.index, one["mocap/stage_x"] * 1e3)
    ax[0].set(ylabel="stage x (mm)")
    ax[1].plot(one.index, one["loadcell/normal_n"])
    ax[1].set(ylabel="plate force (N)", xlabel="t (s)")
    fig.suptitle(f"step 25: {s.steps.frequency_hz[25]:g} Hz")
    fig.savefig(out, dpi=110)
    plt.close(fig)


def chart_picture(out: Path) -> None:
    """The contact chart, from its benchmark's table (no physics here)."""
    import pandas as pd

    from beambench.studies.contact_chart import chart_figure

    chart_figure(pd.read_csv(ROOT / PICTURES["contact_chart.png"].data[0]), out)


def _chart_code() -> list[Callable]:
    from beambench.studies import contact_chart as c

    return [chart_picture, c.chart_figure, c.shipped_point, c.same_physics, c.front_check, c._front_panel]


def _search_code() -> list[Callable]:
    from beambench.studies.contact_search_figure import plot_contact_search

    return [contact_search_picture, plot_contact_search]


# pictures drawn from a benchmark's results: their drawing (here), and the code whose source their stamp hashes
DRAWERS: dict[str, Callable[[Path], None]] = {
    "contact_chart.png": chart_picture,
    "contact_search.png": contact_search_picture,
}
DRAWN_FROM_DATA: dict[str, Callable[[], list[Callable]]] = {
    "contact_chart.png": _chart_code,
    "contact_search.png": _search_code,
}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", default="", help="comma-separated picture names (default: all)")
    args = ap.parse_args(argv)
    only = {n.strip() for n in args.only.split(",") if n.strip()} or set(PICTURES)
    unknown = only - set(PICTURES)
    if unknown:
        raise SystemExit(f"unknown picture(s) {', '.join(sorted(unknown))}; known: {', '.join(PICTURES)}")
    IMG.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="beambench-docs-") as tmp:
        out = Path(tmp)
        for name in sorted(n for n in only if n in DRAWERS):  # drawn from a benchmark's results, no run
            DRAWERS[name](out / name)
            stamp(out / name, name)
        os.environ["BEAMBENCH_USER_DIR"] = str(out / "user")
        wanted = {p for n in only for p in PICTURES[n].protocols}
        for protocol in ("contact_sweep", "walker_sweep", "walker_track"):
            if protocol not in wanted:
                continue
            print(f"running {protocol} ...", file=sys.stderr)
            session = _beambench("run", protocol, "--rerun", "off", "--out", str(out), "--name", protocol)
            report = _beambench("analyze", str(session), "--out", str(out / f"{protocol}_report"), "--no-write", "-q")
            for name in sorted(only):
                pic = PICTURES[name]
                if protocol not in pic.protocols:
                    continue
                if pic.how.startswith("beambench analyze: "):
                    stamp(report.parent / pic.how.removeprefix("beambench analyze: "), name)
                elif pic.how.startswith("beambench view"):
                    at = pic.how.rsplit(" ", 1)[-1]
                    shot = out / name
                    _beambench("view", str(session), "--screenshot", str(shot), "--at", at)
                    stamp(shot, name)
                else:
                    notebook_picture(session, out / name)
                    stamp(out / name, name)
    print(f"wrote {IMG}")


if __name__ == "__main__":
    main()
