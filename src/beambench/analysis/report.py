"""The analysis report: PNG figures, a per-step CSV and an ``index.html`` with the session's provenance.

``make_report([analysis], out)`` for one session; with two or more analyses every figure overlays them
(``beambench compare``). The figures are those registered in :mod:`beambench.analysis.figures` for the
sessions' rig (contact: trajectory grid, contact frequency, forces, direction at contact, ellipses, drive
accuracy; walker: walking speed, body trajectory, feet paths, gait, ellipses, drive accuracy; release: the
tip's hold, release and decay), plus the clock-sync diagnostics where there are device clocks to fit.
"""

from __future__ import annotations

import html
from collections.abc import Callable, Collection
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from beambench.acquisition.protocol.scenes import SceneInfo, scene_or_unknown
from beambench.analysis.drift import drift_table
from beambench.analysis.figures import FIGURES, FigureSpec, ReportOptions
from beambench.analysis.figures.style import R2_SENSE_MIN
from beambench.analysis.release import release_table
from beambench.analysis.report_notes import completeness_notes, contact_notes
from beambench.analysis.session_analysis import SessionAnalysis
from beambench.sinks.session_file.reader import session_warnings

__all__ = ["SUMMARY_COLUMNS", "figures_of", "make_report", "summary_table", "write_html"]


# ---------------------------------------------------------------------------------------------- html/csv


def _prov_rows(a: SessionAnalysis) -> list[tuple[str, str]]:
    g = a.general
    versions = g.get("versions") if isinstance(g.get("versions"), dict) else {}
    rows = [
        ("session file", str(a.path) if a.path else ""),
        ("protocol", a.protocol_name),
        ("rig", a.rig),
        ("backend", a.backend),
        ("started (UTC)", str(g.get("started_utc", ""))),
        ("host", str(g.get("host", ""))),
        ("git SHA", str(g.get("git_sha", ""))),
        ("load-cell calibration", a.calibration_source or "default"),
        ("steps", str(len(a.steps))),
    ]
    if a.frame is not None:
        rows.append(
            (
                "stage frame (world)",
                f"drive {np.round(a.frame.drive, 3).tolist()}, up {np.round(a.frame.up, 3).tolist()}",
            )
        )
    if a.edge_check is not None:
        e = a.edge_check
        rows.append(
            (
                "load-cell sync edge − mocap frame",
                f"median {e.median_s * 1e3:.3f} ms (5–95 %: {e.p05_s * 1e3:.3f} … {e.p95_s * 1e3:.3f} ms, {e.n} edges)",
            )
        )
    if a.delay is not None:
        d = a.delay
        rows.append(
            (
                "encoder → stage marker delay",
                f"{d.delay_s * 1e3:.2f} ms (quality {d.quality:.2f})"
                if np.isfinite(d.delay_s)
                else "n/a (one frequency only)",
            )
        )
    if versions:
        rows.append(("versions", " · ".join(f"{k} {v}" for k, v in versions.items())))
    return rows


def _html_table(df: pd.DataFrame) -> str:
    return df.to_html(index=False, float_format=lambda v: f"{v:.4g}", na_rep="", border=0, classes="data")


# The per-step columns shown in the report (the CSV has them all), with their headers and units.
SUMMARY_COLUMNS = {
    "frequency_hz": "drive (Hz)",
    "measured_frequency_hz": "measured (Hz)",
    "stage_amplitude_mm": "stage amplitude (mm)",
    "regime": "contact regime",
    "contacts_per_cycle": "contacts per cycle",
    "contact_frequency_hz": "contact frequency (Hz)",
    "peak_normal_n": "peak normal force (N)",
    "mean_tangential_n": "mean tangential force (N)",
    "touchdown_velocity_mm_s": "foot speed at touchdown (mm/s)",
    "tip_major_mm": "tip ellipse major (mm)",
    "tip_minor_mm": "tip ellipse minor (mm)",
    "tip_sense": "tip sense",
    "tip_ellipse_r2": "tip ellipse R²",
    "body_speed_mm_s": "body speed (mm/s)",
}
WALKER_COLUMNS = {
    "frequency_hz": "drive (Hz)",
    "motor_frequency_hz": "motor encoder (Hz)",
    "body_speed_mm_s": "body speed (mm/s)",
    "body_speed_stderr_mm_s": "± (mm/s)",
    "foot_left_major_mm": "left foot ellipse major (mm)",
    "foot_left_minor_mm": "left foot ellipse minor (mm)",
    "foot_left_sense": "left foot sense",
    "foot_left_ellipse_r2": "left foot ellipse R²",
}


def summary_table(table: pd.DataFrame, scene: SceneInfo | None = None) -> pd.DataFrame:
    """The readable subset of the per-step table for a rig's scene: a dozen columns with units in the headers
    (a walking body's speed and feet where the scene walks), sense marked uncertain where the ellipse fit is poor."""
    columns = WALKER_COLUMNS if scene is not None and scene.walks else SUMMARY_COLUMNS
    cols = [c for c in columns if c in table]
    out = _sorted(table)[cols].copy()
    for m in ("tip", "foot_left"):
        sense, r2 = f"{m}_sense", f"{m}_ellipse_r2"
        if sense in out and r2 in out:
            poor = ~(out[r2].astype(float) >= R2_SENSE_MIN) & (out[sense].fillna("").astype(str) != "")
            out.loc[poor, sense] = out.loc[poor, sense].astype(str) + " (uncertain)"
    return out.rename(columns=columns)


def _per_step_html(a: SessionAnalysis) -> str:
    """The session's per-step table: the release test's decay fit, else the rig's summary columns."""
    if scene_or_unknown(a.rig).free_decay:
        return "<p>Release and decay, fitted as a second-order system released from rest:</p>" + _html_table(
            release_table(a)
        )
    return _html_table(summary_table(a.table, scene_or_unknown(a.rig)))


def _sorted(t: pd.DataFrame) -> pd.DataFrame:
    return t.sort_values("frequency_hz", kind="stable") if "frequency_hz" in t else t


def _warning_banners(analyses: list[SessionAnalysis]) -> list[str]:
    """A banner at the top for each warning a session's run gave (``/general/warnings``)."""
    banners = []
    for a in analyses:
        who = "" if len(analyses) == 1 else f" ({html.escape(a.label)})"
        banners += [
            f"<p class='warn'><strong>Warning from the run{who}:</strong> {html.escape(w)}</p>"
            for w in session_warnings(a.general)
        ]
    return banners


def write_html(
    analyses: list[SessionAnalysis],
    out: Path,
    figures: dict[str, tuple[Path, str]],
    csv_name: str,
    drift: pd.DataFrame | None = None,
) -> Path:
    """``index.html`` with the figures, provenance, clock fits, the reference-step drift and the per-step table."""
    title = "beambench report — " + " vs ".join(html.escape(a.label) for a in analyses)
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>{title}</title>",
        "<style>body{font-family:system-ui,sans-serif;margin:2em;max-width:1500px}"
        "img{max-width:100%;border:1px solid #ddd}figure{margin:1.5em 0}figcaption{color:#444;font-size:0.9em}"
        "table{border-collapse:collapse;font-size:0.85em}td,th{padding:2px 8px;border-bottom:1px solid #eee;text-align:left}"
        "pre{background:#f6f6f6;padding:0.8em;overflow:auto}.cols{display:flex;gap:2em;flex-wrap:wrap}"
        ".note{background:#fff4e0;border-left:4px solid #ff7f0e;padding:0.6em 1em}"
        ".warn{background:#fde8e8;border-left:4px solid #d62728;padding:0.6em 1em}</style></head><body>",
        f"<h1>{title}</h1>",
        *completeness_notes(analyses),
        *_warning_banners(analyses),
        *contact_notes(analyses),
        f"<p>Per-step results: the main columns are at the end of this page; all of them are in "
        f"<a href='{csv_name}'>{csv_name}</a>. Record windows only (t_settled → t_end of each step), "
        "all streams on the host clock through the fitted device clocks.</p>",
        "<h2>Provenance</h2><div class='cols'>",
    ]
    for a in analyses:
        rows = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in _prov_rows(a))
        proto = html.escape(str(a.general.get("protocol", "")))
        ident = a.general.get("identity")
        ident_text = html.escape(
            yaml.safe_dump(ident, sort_keys=False) if isinstance(ident, dict) else str(ident or "")
        )
        parts.append(
            f"<div><h3>{html.escape(a.label)}</h3><table>{rows}</table>"
            f"<details><summary>protocol YAML</summary><pre>{proto}</pre></details>"
            f"<details><summary>devices and model (identity)</summary><pre>{ident_text}</pre></details></div>"
        )
    parts.append("</div><h2>Figures</h2>")
    for key, (p, caption) in figures.items():
        parts.append(
            f"<figure><img src='{p.name}' alt='{key}'><figcaption>{html.escape(caption)}</figcaption></figure>"
        )
    parts += _drift_html(drift if drift is not None else pd.DataFrame())
    parts.append("<h2>Clock fits</h2>")
    for a in analyses:
        cols = [
            "stream",
            "method",
            "drift_ppm",
            "offset_s",
            "n",
            "n_used",
            "n_rejected",
            "residual_median_us",
            "residual_p95_us",
            "residual_max_us",
            "rtt_min_us",
            "bound_us",
        ]
        st = a.sync_table
        parts.append(f"<h3>{html.escape(a.label)}</h3>" + _html_table(st[[c for c in cols if c in st]]))
    parts.append(
        f"<h2>Per-step results</h2><p>The main columns; every column ({max(len(a.table.columns) for a in analyses)}) "
        f"is in <a href='{csv_name}'>{csv_name}</a>.</p>"
    )
    for a in analyses:
        parts.append(f"<h3>{html.escape(a.label)}</h3><div style='overflow-x:auto'>" + _per_step_html(a) + "</div>")
    parts.append("</body></html>")
    path = out / "index.html"
    path.write_text("\n".join(parts))
    return path


def make_report(
    analyses: list[SessionAnalysis],
    out: str | Path,
    force_at: list[float] | None = None,
    progress: Callable[[str], None] | None = None,
    only: Collection[str] | None = None,
) -> Path:
    """Write the figures of the sessions' rig (those named in ``only``, if given), ``steps.csv`` and
    ``index.html`` into ``out``; returns the html path. ``progress(key)`` is called before each figure
    (``len(figures_of(analyses, only))`` of them)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if len(analyses) == 1:
        table = analyses[0].table
    else:
        table = pd.concat([a.table.assign(session=a.label) for a in analyses], ignore_index=True)
        table = table[["session", *[c for c in table.columns if c != "session"]]]
    csv_name = "steps.csv"
    table.to_csv(out / csv_name, index=False)
    drift = drift_tables(analyses)
    if len(drift):
        drift.to_csv(out / DRIFT_CSV, index=False)
    options = ReportOptions(force_at)
    figures: dict[str, tuple[Path, str]] = {}
    for spec in _figure_specs(analyses, only):
        if progress is not None:
            progress(spec.key)
        p = spec.draw(analyses, out / f"{spec.key}.png", options)
        if p is not None:
            figures[spec.key] = (p, spec.caption_for(analyses[0].rig))
    return write_html(analyses, out, figures, csv_name, drift)


DRIFT_CSV = "drift.csv"


def drift_tables(analyses: list[SessionAnalysis]) -> pd.DataFrame:
    """The reference-step drift of every session with reference steps (a ``session`` column when several)."""
    parts = [drift_table(a.table).assign(session=a.label) for a in analyses]
    parts = [p for p in parts if len(p)]
    if not parts:
        return pd.DataFrame()
    t = pd.concat(parts, ignore_index=True)
    return t[["session", *[c for c in t.columns if c != "session"]]] if len(analyses) > 1 else t.drop(columns="session")


def _drift_html(drift: pd.DataFrame) -> list[str]:
    if not len(drift):
        return []
    return [
        "<h2>Drift at the reference steps</h2><p>Linear trend per hour of each reference-step result with its "
        "standard error; <em>significant</em> where |trend|/SE exceeds the two-sided 5 % t value and the change "
        f"over the session exceeds the analysis's resolution (<a href='{DRIFT_CSV}'>{DRIFT_CSV}</a>).</p>",
        _html_table(drift),
    ]


def _figure_specs(analyses: list[SessionAnalysis], only: Collection[str] | None) -> list[FigureSpec]:
    """The figures of the sessions' rig(s), or those among them named in ``only``."""
    specs = FIGURES.for_rigs({a.rig for a in analyses})
    return specs if only is None else [s for s in specs if s.key in only]


def figures_of(analyses: list[SessionAnalysis], only: Collection[str] | None = None) -> list[str]:
    """The keys of the figures a report on these sessions draws (some may have nothing to show), or of those
    among them named in ``only``."""
    return [spec.key for spec in _figure_specs(analyses, only)]
