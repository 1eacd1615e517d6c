"""A dry run checks every field without MuJoCo or python-can: validation (``beambench.session.checks.validate``)
reads the model-name grammar, the scenes' parameter dataclasses and the CAN log formats from light modules, and the
expected run time comes from measured tables (the timing table where it plans the run, else the stepping costs in
``sim_backend/step_costs.csv``), never from building the scene. Neither a dry run nor a sim run that records a
session loads pandas: planning reads the timing table's CSV itself, the session writer takes no DataFrame (pandas
costs each ``beambench`` process ~0.3 s to import)."""

from __future__ import annotations

import functools
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
    print("LOADED " + json.dumps(sorted(m for m in ("mujoco", "can", "serial", "pandas") if m in sys.modules)))
"""


def _loaded(args: list[str]) -> tuple[int, list[str], str]:
    """Exit code, the heavy packages loaded and the output of ``beambench ARGS`` in a fresh interpreter (a command
    line two tests both run, e.g. the shipped contact sweep's dry run, runs once per worker)."""
    return _loaded_once(tuple(args))


@functools.cache
def _loaded_once(args: tuple[str, ...]) -> tuple[int, list[str], str]:
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


def _shipped_run_protocols() -> list[str]:
    """Every shipped protocol ``beambench run`` takes (the sweep files, with ``base:``, are ``beambench sweep``'s)."""
    from beambench.common.resources import shipped_dir

    files = sorted(shipped_dir("protocols").glob("*.yaml"))
    assert len(files) >= 6, files
    return [f.stem for f in files if not any(ln.startswith("base:") for ln in f.read_text().splitlines())]


@pytest.mark.parametrize("protocol", _shipped_run_protocols())
def test_every_shipped_protocols_sim_dry_run_is_estimated_without_mujoco_or_python_can(protocol: str) -> None:
    code, loaded, out = _loaded(["run", protocol, "--dry-run"])
    assert code == 0, out
    line = out[out.index("expected run time here:") :]
    assert "not estimated" not in line and "of stepping" in line, line
    assert loaded == [], out


def test_the_shipped_sweep_files_dry_runs_load_neither() -> None:
    from beambench.common.resources import shipped_dir

    sweeps = [f.stem for f in shipped_dir("protocols").glob("*.yaml") if "base:" in f.read_text()]
    assert sweeps
    for name in sweeps:
        code, loaded, out = _loaded(["sweep", name, "--dry-run"])
        assert code == 0 and not {"mujoco", "can", "serial"} & set(loaded), out  # a sweep's spec is a table: pandas


def test_a_sim_dry_run_the_tables_do_not_cover_says_so_without_mujoco(tmp_path) -> None:
    """On the sim, the expected run time comes from the measured timing table where it covers the run, else from
    the measured stepping costs; a run neither covers (here a fixed timestep nobody measured) is not estimated, and
    the dry run names the command that measures it. None of them loads MuJoCo."""
    auto = tmp_path / "auto.yaml"
    auto.write_text("rig: contact\nsweep: {frequencies: [10, 20, 30]}\nsim: {model: auto}\n")
    code, loaded, out = _loaded(["run", str(auto), "--dry-run"])
    assert code == 0 and "from the measured timing table" in out, out
    assert loaded == [], out
    code, loaded, out = _loaded(["run", "contact_sweep", "--dry-run"])  # rod5g: not in the timing table
    assert code == 0 and "from the measured cost table step_costs.csv" in out, out
    assert loaded == [], out
    odd = tmp_path / "odd.yaml"
    odd.write_text("rig: contact\nsweep: {frequencies: [10, 20]}\nsim: {model: rod3g, timestep: 3.0e-5}\n")
    code, loaded, out = _loaded(["run", str(odd), "--dry-run"])
    assert code == 0 and "not estimated" in out and "bench_step_costs.py" in out, out
    assert loaded == [], out


def test_a_sim_run_records_its_session_without_pandas(tmp_path) -> None:
    protocol = tmp_path / "short.yaml"
    protocol.write_text("name: short\nrig: contact\nsweep: {frequencies: [10]}\nsettle_s: 0.2\nrecord_s: 0.2\n")
    code, loaded, out = _loaded(["run", str(protocol), "--rerun", "off", "--out", str(tmp_path)])
    assert code == 0 and len(list(tmp_path.glob("short_sim_*.h5"))) == 1, out
    assert loaded == ["mujoco"], out


def test_measured_costs_are_filed_under_the_runs_key_and_read_back(tmp_path) -> None:
    """The table's rows for a protocol are what its dry run looks up: a short contact run measured (this loads
    MuJoCo, in the test's process), written as the bench writes it, and the estimate read from it."""
    import csv

    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.session import estimate
    from beambench.session.slices import sim_slice

    protocol = parse_protocol("rig: contact\nsweep: {frequencies: [5, 10, 15]}\nsettle_s: 1\nrecord_s: 2\n")
    rows = estimate.measure_step_costs(protocol)
    sim = sim_slice(protocol)
    assert [float(r["frequency_hz"]) for r in rows] == [5.0, 10.0, 15.0]
    assert all(r[k] == v for r in rows for k, v in estimate.cost_key(sim).items())
    assert all(float(r["cpu_s_per_sim_s"]) > 0 for r in rows)
    table = tmp_path / "step_costs.csv"
    with open(table, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(estimate.COST_FIELDS))
        w.writeheader()
        w.writerows(rows)
    got = estimate.table_run_time(protocol, sim, estimate.read_costs(table))
    assert got is not None and got.at_hz == 15.0 and got.params == sim.params
    expected = sum(3.0 * float(r["cpu_s_per_sim_s"]) for r in rows) / got.parallel  # 3 s of rig time per step
    assert got.seconds == pytest.approx(expected)


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
