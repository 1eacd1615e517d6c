"""The files a calibration writes: the calibrated parameter set and a runnable protocol that selects it."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from beambench.studies.twin_calibration.targets import Targets

if TYPE_CHECKING:
    from beambench.sim.models.params import BeamParams


@dataclass(frozen=True)
class CalibratedSet:
    """What a rig writes: the calibrated ``params`` with its ``rig_block``, the ``values`` found, the prior set
    (``prior``) and model they came from, the shipped protocol used when the targets carry none, what goes into
    the protocol's ``sim:`` block besides the parameter set (``sim_extra``) and the files' notes."""

    params: BeamParams
    rig_block: dict[str, Any]
    values: dict[str, float]
    prior: str
    model: str
    shipped_protocol: str
    sim_extra: dict[str, Any] = field(default_factory=dict)
    params_note: str = "."
    protocol_note: str = ""
    rig_label: str = ""


def write_calibrated_protocol(cal: CalibratedSet, targets: Targets, out_dir: Path, name: str) -> Path:
    """Write ``out_dir/<name>_params.yaml`` (``cal.params`` with ``cal.rig_block``) and ``out_dir/<name>.yaml``:
    the session's protocol (or the shipped ``cal.shipped_protocol``) with ``sim.params`` = that file's absolute
    path plus ``cal.sim_extra``; the sweep is extended to cover the targets if it stops short. Every calibratable
    rig writes its outputs through here; a protocol that would not load is refused, never written."""
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.common.resources import shipped_dir

    params = cal.params
    beam = {k: v for k, v in params.to_dict().items() if k not in ("name", "model", "source", "rig", "material")}
    beam["material"] = asdict(params.material)
    what = f" ({cal.rig_label})" if cal.rig_label else ""
    params_doc = {
        "name": name,
        "model": params.model,
        "source": f"beambench calibrate sim{what} against {targets.source} (prior: {cal.prior}); "
        + ", ".join(f"{k} = {v:.5g}" for k, v in cal.values.items()),
        "beam": {k: float(v) if isinstance(v, float | int) else v for k, v in beam.items()},
        "rig": cal.rig_block,
    }
    params_path = (out_dir / f"{name}_params.yaml").resolve()
    params_path.write_text(
        "# Calibrated by `beambench calibrate sim` (see the report beside this file). SI units"
        + cal.params_note
        + "\n"
        + yaml.safe_dump(params_doc, sort_keys=False)
    )
    text = targets.protocol_text or (shipped_dir("protocols") / cal.shipped_protocol).read_text()
    doc = yaml.safe_load(text)
    doc["name"] = name
    doc["backend"] = "sim"
    doc.setdefault("sim", {})
    doc["sim"]["params"] = str(params_path)
    doc["sim"]["model"] = cal.model
    doc["sim"].update(cal.sim_extra)
    doc = extended_sweep(doc, targets)
    out = out_dir / f"{name}.yaml"
    header = f"# Calibrated by `beambench calibrate sim` against {targets.source}.\n# {cal.protocol_note}\n"
    body = yaml.safe_dump(doc, sort_keys=False, allow_unicode=True)
    parse_protocol(body, str(out))  # refuse to write a protocol that would not load
    out.write_text(header + body)
    return out.resolve()


def extended_sweep(doc: dict[str, Any], targets: Targets) -> dict[str, Any]:
    """The protocol mapping ``doc`` with its sweep (and frequency limit) extended up to the targets' highest
    frequency when it stops short (in place; returned). A protocol without ``limits.max_frequency_hz`` has the
    parser's default limit (:class:`~beambench.acquisition.protocol.schema.Limits`), raised only as far as the targets."""
    from beambench.acquisition.protocol.schema import Limits

    top = float(max(targets.frequencies)) if len(targets.table) else 0.0
    sweep = doc.get("sweep", {})
    if isinstance(sweep, dict) and "stop" in sweep and top > float(sweep["stop"]):
        sweep["stop"] = math.ceil(top)
        lim = doc.setdefault("limits", {})
        lim["max_frequency_hz"] = max(float(lim.get("max_frequency_hz", Limits().max_frequency_hz)), math.ceil(top))
    return doc
