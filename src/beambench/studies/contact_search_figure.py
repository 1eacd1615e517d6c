"""The contact twin's box search in one picture (``benchmarks/bench_contact_search.py`` writes the CSV): which
share of the physical box meets each of the paper's landmarks, with each model option on and off, and the maps of
the points that meet the most."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from beambench.common.figures import new_figure

LANDMARK_LABELS = {
    "continuous_below_hz": "continuous\nbelow 18±2 Hz",
    "half_at_hz": "lowest ½\nat 26±2 Hz",
    "third_at_hz": "lowest ⅓\nat 38±2 Hz",
    "sign_26": "tangential −\nat 26 Hz",
    "sign_40": "tangential +\nat 40 Hz",
}
REGIME_COLOURS = {
    "C": "#1b7837",
    "1": "#a6dba0",
    "2": "#fdb863",
    "h": "#2166ac",
    "t": "#b2182b",
    "q": "#f4a582",
    ".": "#bababa",
}
REGIME_NAMES = {
    "C": "continuous",
    "1": "1 per cycle",
    "2": "2 per cycle",
    "h": "½",
    "t": "⅓",
    "q": "¼",
    ".": "irregular / other",
}
NO_CONTACT = "#ffffff"


def plot_contact_search(
    csv_path: str | Path,
    out: str | Path,
    frequencies: tuple[float, ...],
    shipped: tuple[str, int] | None = None,
    top: int = 12,
) -> Path:
    """Left: the fraction of the points meeting each landmark (all points; β against the loss factor; the frame's
    mass spread against a rigid frame). Right: the maps of the ``top`` points by landmarks met (``shipped``: the
    shipped point's screen map and landmarks met, first), one row each, coloured by regime at the screen's ``frequencies``."""
    df = pd.read_csv(csv_path, dtype={"map": str}).fillna({"map": ""})
    n = len(df)
    fig = new_figure(figsize=(13, 5.6))
    left, right = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    groups = {
        f"all {n} points": df,
        "β (stiffness-prop.)": df[df["damping"] == 0],
        "loss factor η": df[df["damping"] == 1],
        "frame mass spread": df[df["frame"] == 0],
        "rigid frame (gyration)": df[df["frame"] == 1],
    }
    keys = list(LANDMARK_LABELS)
    width = 0.8 / len(groups)
    x = np.arange(len(keys) + 1)
    top_frac = 0.0
    for i, (name, g) in enumerate(groups.items()):
        counts = [int(g[f"met_{k}"].sum()) for k in keys] + [int((g["met"] >= 3).sum())]
        frac = [c / len(g) if len(g) else 0.0 for c in counts]
        top_frac = max(top_frac, *frac)
        xs = x + (i - len(groups) / 2 + 0.5) * width
        left.bar(xs, frac, width, label=f"{name} ({len(g)})")
        if i == 0:  # the whole sample's counts over its bars
            for xi, fi, count in zip(xs, frac, counts):
                left.text(xi, fi, str(count), ha="center", va="bottom", fontsize=7)
    left.set_xticks(x, [*LANDMARK_LABELS.values(), "3 or more\nof the 5"], fontsize=8)
    left.set_ylabel("fraction of points meeting it (count over the first bar)")
    left.set_ylim(0, max(0.05, 1.3 * top_frac))
    left.legend(fontsize=8, loc="upper left")
    resting = float((df["preload_mm"] > 0).mean()) if n else 0.0
    screened = int(df["screened"].sum())
    left.set_title(
        f"the physical box: {n} Sobol points, the foot resting on the plate at rest in {resting:.0%};\n"
        f"{screened} screened, {n - screened} hanging > 1.5 mm clear (meet none)",
        fontsize=10,
    )

    best = df.sort_values(["met", "index"], ascending=[False, True]).head(top)
    rows: list[tuple[str, str, int]] = [("shipped", shipped[0], shipped[1])] if shipped else []
    rows += [(f"#{int(r['index'])}", str(r["map"]), int(r["met"])) for _, r in best.iterrows()]
    for j, (label, code, count) in enumerate(rows):
        for k, step in enumerate(code[: len(frequencies)]):
            colour = REGIME_COLOURS.get(step, NO_CONTACT if step == "-" else REGIME_COLOURS["."])
            right.add_patch(_cell(k, j, colour))
        right.text(-0.3, j + 0.5, f"{label}  {count}/5", ha="right", va="center", fontsize=8)
    right.set_xlim(0, len(frequencies))
    right.set_ylim(len(rows), 0)
    right.set_xticks(np.arange(len(frequencies)) + 0.5, [f"{f:g}" for f in frequencies], fontsize=7)
    right.set_yticks([])
    right.set_xlabel("drive frequency (Hz), the screen's stepped sweep")
    right.set_title("the points meeting the most landmarks (met of 5): regime per step", fontsize=10)
    for regime, name in REGIME_NAMES.items():
        right.bar(0, 0, color=REGIME_COLOURS[regime], label=name)
    right.bar(0, 0, color=NO_CONTACT, edgecolor="#999999", label="no contact")
    right.legend(fontsize=7, ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.12))
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return Path(out)


def _cell(k: int, j: int, colour: str):
    from matplotlib.patches import Rectangle

    return Rectangle((k, j + 0.1), 1, 0.8, facecolor=colour, edgecolor="#999999", linewidth=0.3)
