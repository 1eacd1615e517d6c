"""The sweep's chart: the ellipse metrics against the first swept parameter, titled with the point it shows
and the settings held fixed."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from beambench.acquisition.protocol.scenes import scene_or_unknown
from beambench.common.figures import new_figure
from beambench.studies.sweep.run import SweepSpec


def _value_label(val: Any) -> str:
    return f"{val:g}" if isinstance(val, (int, float)) else str(val)


AXIS_LABELS = {
    "twist_deg": "twist angle φ (deg)",
    "frequency_hz": "drive frequency (Hz)",
    "k": "bending stiffness k (N·m/rad)",
    "b": "joint damping b (N·m·s/rad)",
    "gap_mm": "plate gap h′ (mm)",
    "amplitude_mm": "stage amplitude A (mm)",
    "youngs_modulus": "Young's modulus E (Pa)",
    "beta": "stiffness-proportional damping β (s)",
    "model": "beam model",
    "params": "parameter set",
}


def axis_label(column: str) -> str:
    """A swept column's name in words, with its unit (``twist_deg`` → ``twist angle φ (deg)``)."""
    return AXIS_LABELS.get(column, column.replace("_", " "))


def sweep_title(spec: SweepSpec, shown: list[str]) -> str:
    """The sweep chart's title: which point's ellipse, against what, and the settings held fixed (the drive
    frequency when it does not vary, the amplitude), e.g. "twist_sweep: tip path ellipse vs twist angle φ at
    15 Hz, A = 2 mm (free_beam)"."""
    point = "foot path relative to the stage" if scene_or_unknown(spec.scene).plate else "tip path"
    held: list[str] = []
    freqs = spec.frequency_values()
    if "frequency_hz" not in shown and freqs:
        held.append(f"{freqs[0]:g} Hz" if len(freqs) == 1 else f"{min(freqs):g}–{max(freqs):g} Hz")
    amplitude = spec.base.get("amplitude_mm")
    if amplitude is not None and "amplitude_mm" not in shown:
        held.append(f"A = {float(amplitude):g} mm")
    against = " vs " + axis_label(shown[0]).split(" (")[0] if shown else ""
    return f"{spec.name}: {point} ellipse{against}" + (f" at {', '.join(held)}" if held else "") + f" ({spec.scene})"


def plot_sweep(df: pd.DataFrame, spec: SweepSpec, path: str | Path) -> Path | None:
    """Metrics against the first swept parameter (a scene with a plate under the foot: the foot's axes relative to
    the stage and contacts per cycle; else the tip's major/minor axes and tilt, as the paper's Fig. 2e)."""

    axes = [a for a in spec.axes() if a in df.columns]
    if not axes or df.empty:
        return None
    x, series = axes[0], (axes[1] if len(axes) > 1 else None)
    plate = scene_or_unknown(spec.scene).plate
    prefix = "foot_rel" if plate else "tip"
    metrics = [(f"{prefix}_major_mm", "major axis (mm)"), (f"{prefix}_minor_mm", "minor axis (mm)")]
    if plate:
        metrics.append(("contacts_per_cycle", "contacts per drive cycle"))
    else:
        metrics.append((f"{prefix}_tilt_deg", "tilt of the major axis (deg)"))
    fig = new_figure(figsize=(5 * len(metrics), 4), layout="constrained")
    axs = fig.subplots(1, len(metrics), squeeze=False)[0]
    groups = [(None, df)] if series is None else list(df.groupby(series, sort=True))
    for ax, (col, label) in zip(axs, metrics):
        for val, g in groups[:12]:
            g = g.sort_values(x)
            ax.plot(
                g[x],
                g[col],
                "o-",
                ms=3,
                label=None if series is None else f"{axis_label(series)} = {_value_label(val)}",
            )
        ax.set(xlabel=axis_label(x), ylabel=label)
        ax.grid(alpha=0.3)
    if series is not None:
        axs[0].legend(fontsize=7)
    fig.suptitle(sweep_title(spec, [x, *([series] if series else [])]))
    path = Path(path)
    fig.savefig(path, dpi=120)
    return path
