"""A dry run checks every field without MuJoCo or python-can: validation (``beambench.session.checks.validate``)
reads the model-name grammar, the scenes' parameter dataclasses and the CAN log formats from light modules. The
one part of a dry run that may load MuJoCo is timing a scene that has no measured timing table on the sim."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

# runs ``beambench run …`` in a fresh interpreter, then prints which heavy packages it loaded (the command's own
# exit ends in SystemExit: the finally prints either way)
_WRAPPER = """
import json, sys
from beambench.cli import main
sys.argv = ["beambench", *json.loads(sys.argv[1])]
try:
    main()
finally:
    print("LOADED " + json.dumps(sorted(m for m in ("mujoco", "can", "serial") if m in sys.modules)))
"""


def _loaded(args: list[str]) -> tuple[int, list[str], str]:
    res = subprocess.run(
        [sys.executable, "-c", _WRAPPER, json.dumps(args)], capture_output=True, text=True, timeout=120
    )
    line = next(ln for ln in res.stdout.splitlines() if ln.startswith("LOADED "))
    return res.returncode, json.loads(line.removeprefix("LOADED ")), res.stdout + res.stderr


@pytest.mark.parametrize(("protocol", "backend"), [("contact_sweep", "hardware"), ("walker_sweep", "emulated")])
def test_a_dry_run_loads_neither_mujoco_nor_python_can(protocol: str, backend: str) -> None:
    code, loaded, out = _loaded(["run", protocol, "--dry-run", "--backend", backend])
    assert code == 0, out
    assert "Dry run:" in out and "limits: max_frequency_hz=" in out
    assert loaded == [], out


def test_a_sim_dry_run_estimated_from_the_measured_table_loads_no_mujoco(tmp_path) -> None:
    """On the sim, the expected run time comes from the measured timing table where it covers the run; only a
    run the table does not cover is timed on its physics here (that, and only that, loads MuJoCo)."""
    auto = tmp_path / "auto.yaml"
    auto.write_text("rig: contact\nsweep: {frequencies: [10, 20, 30]}\nsim: {model: auto}\n")
    code, loaded, out = _loaded(["run", str(auto), "--dry-run"])
    assert code == 0 and "from the measured timing table" in out, out
    assert loaded == [], out
    code, loaded, out = _loaded(["run", "contact_sweep", "--dry-run"])  # rod5g: not in the table, timed here
    assert code == 0 and "measured here" in out, out
    assert loaded == ["mujoco"], out


def test_a_bad_field_is_refused_by_the_dry_run_without_mujoco(tmp_path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("rig: contact\nsweep: {frequencies: [10, 20]}\nsim: {model: rod999}\n")
    code, loaded, out = _loaded(["run", str(bad), "--dry-run"])
    assert code == 2 and "sim.model" in out and "unknown beam model" in out, out
    assert loaded == [], out
    good = tmp_path / "good.yaml"
    good.write_text("rig: contact\nsweep: {frequencies: [10, 20]}\n")
    code, loaded, out = _loaded(["run", str(good), "--dry-run", "-b", "emulated", "--can-log", str(tmp_path / "x.txt")])
    assert code == 2 and "--can-log" in out and ".asc" in out, out
    assert loaded == [], out


def test_validate_returns_the_plan_the_slices_and_the_limits() -> None:
    from beambench.acquisition.protocol.plan import plan
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.session.checks import validate

    protocol = parse_protocol("rig: contact\nsweep: {frequencies: [10, 30]}\nlimits: {max_frequency_hz: 50}\n")
    checked = validate(protocol, "sim")
    assert checked.steps == plan(protocol) and [s.frequency_hz for s in checked.steps] == [10, 30]
    assert checked.limits.max_frequency_hz == 50
    assert checked.slices.sim is not None and checked.slices.sim.scene == "contact"
    on_hardware = validate(protocol, "hardware")
    assert on_hardware.slices.sim is None and on_hardware.slices.markers
