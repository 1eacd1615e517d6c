"""Run a protocol the calibrator wrote exactly as its user will: ``beambench run`` on the sim backend, then
``beambench analyze`` — the calibrator's verify stage (``CalibratableRig.run_written``) judges its candidates on
these maps. The search's own maps classify the simulated load cells directly (no device clocks, sampling or sync)
and differ from the analysed session at marginal labels (a continuous edge where the foot barely lifts); the
analysed session is the map the user sees, and the sim backend is deterministic for a given protocol and seed.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Any

import yaml

from beambench.common.errors import BeambenchError

# the analysis columns the calibrator's objectives and reports read (those a session has)
STEP_COLUMNS = (
    "frequency_hz",
    "regime",
    "contacts_per_cycle",
    "in_contact_fraction",
    "n_contacts",
    "peak_normal_n",
    "mean_tangential_n",
    "tangential_sign",
    "touchdown_direction",
    "tip_major_mm",
    "tip_minor_mm",
    "body_speed_mm_s",
)


class WrittenRunError(BeambenchError, RuntimeError):
    """A written protocol did not run to completion (interrupted, device fault): its map is not a result."""


def run_written_protocol(path: Path, seed: int | None = None) -> dict[str, Any]:
    """Run the protocol at ``path`` on the sim backend (``seed`` instead of its ``sim.seed`` when not None) into
    a temporary session file, analyse it and return ``{"steps": [row per step], "extras": {...}}`` with the
    :data:`STEP_COLUMNS` the analysis has. A run that does not complete raises :class:`WrittenRunError`."""
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.analysis.session_analysis import analyze_session
    from beambench.common.yaml_config import load_yaml_file
    from beambench.session.run import run_session
    from beambench.sinks.session_file.reader import read_session

    doc, _ = load_yaml_file(path)  # kind and size checked before the read
    doc["backend"] = "sim"
    if seed is not None:
        doc.setdefault("sim", {})["seed"] = int(seed)
    text = yaml.safe_dump(doc, sort_keys=False, allow_unicode=True)
    protocol = parse_protocol(text, str(path))
    with tempfile.TemporaryDirectory(prefix="beambench-verify-") as tmp:
        session_path = Path(tmp) / "verify.h5"
        result = run_session(protocol, text, "sim", session_path, rerun_mode="off", show_progress=False)
        if result.status != "completed":
            raise WrittenRunError(f"{path}: the run ended {result.status} ({result.message})")
        table = analyze_session(read_session(session_path)).table
    cols = [c for c in STEP_COLUMNS if c in table]
    steps = [{c: _plain(row[c]) for c in cols} for row in table[cols].to_dict("records")]
    for row in steps:
        if not isinstance(row.get("regime", ""), str):
            row["regime"] = ""  # a step without contact data
    return {"steps": steps, "extras": {"verify_protocol": str(path), "seed": doc.get("sim", {}).get("seed")}}


def _plain(v: Any) -> Any:
    """A JSON-friendly scalar (the evaluation log is JSON lines)."""
    if isinstance(v, str):
        return v
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    return f if math.isfinite(f) else float("nan")
