"""What a protocol may name: ``output.name`` uses only the documented fields (no attribute or index access on them,
whatever they are), and a parameter set is used only by a model of the family its file says (docs/safety.md,
"Inputs")."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from beambench.acquisition.protocol.schema import NAME_FIELDS, parse_protocol
from beambench.common.resources import USER_DIR_ENV, shipped_dir
from beambench.common.yaml_config import ConfigError
from conftest import cli, one_line_error

BASE = "name: p\nsweep: {frequencies: [5]}\nsettle_s: 0.1\nrecord_s: 0.1\n"


@pytest.mark.parametrize(
    "template",
    [
        "{protocol.__class__.__mro__}",
        "{protocol.__class__}",
        "{rig.upper}",
        "{date[0]}",
        "{backend[__class__]}",
        "{protocol.__len__.__self__}",
        "{}",
        "{1}",
        "x_{protocol}_{Protocol}",
    ],
)
def test_a_name_template_uses_only_the_documented_fields(template, tmp_path):
    with pytest.raises(ConfigError) as exc:
        parse_protocol(BASE + f'output: {{name: "{template}"}}\n', "p.yaml")
    assert exc.value.field == "output.name" and "\n" not in str(exc.value)
    proto = tmp_path / "p.yaml"
    proto.write_text(BASE + f'output: {{name: "{template}"}}\n')
    one_line_error(*cli("run", str(proto), "--out", str(tmp_path / "data"), "--rerun", "off"), "output.name")
    assert not (tmp_path / "data").exists()


def test_every_documented_field_and_its_format_spec_still_name_a_session():
    template = "_".join(f"{{{f}}}" for f in NAME_FIELDS) + "_{date:>20}"
    p = parse_protocol(BASE + f'output: {{name: "{template}"}}\n', "p.yaml")
    assert p.output.name == template


def _rod_set_as(tmp: Path, name: str) -> Path:
    """The shipped rod parameter set (its file says ``model: rod``) copied to ``name``."""
    path = tmp / name
    path.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(shipped_dir("sim_backend") / "rod_paper.yaml", path)
    return path


@pytest.mark.parametrize("given", ["a path", "a named set"])
def test_a_parameter_set_of_another_model_family_is_refused(given, tmp_path, monkeypatch):
    monkeypatch.setenv(USER_DIR_ENV, str(tmp_path / "user"))
    if given == "a path":
        params = str(_rod_set_as(tmp_path, "rod_params.yaml"))
    else:  # named like a PRB3 set, in the user's folder where `sim.params: <name>` finds it
        _rod_set_as(tmp_path / "user" / "sim_backend", "prb3_renamed.yaml")
        params = "renamed"
    proto = tmp_path / "p.yaml"
    proto.write_text(BASE + f"sim: {{model: prb3, params: {params}}}\n")
    line = one_line_error(*cli("run", str(proto), "--dry-run"), "model: rod", "prb3")
    assert "rod_params.yaml" in line or "prb3_renamed.yaml" in line, line
    proto.write_text(BASE + f"sim: {{model: rod5, params: {params}}}\n")
    if given == "a path":  # the same file for a rod: its own family, accepted
        code, out = cli("run", str(proto), "--dry-run")
        assert code == 0, out


@pytest.mark.parametrize(
    ("clocks", "key"),
    [
        ("clocks: {Mocap: {offset_s: 0.1}}", "Mocap"),  # a stream's name with a capital
        ("clocks: {mocap-x: {offset_s: 0.1}}", "mocap-x"),  # a character no stream name has
        ("clocks: {laser: {drift_ppm: 5}}", "laser"),  # well formed, but no such stream registered
        ("Mocap_clock: {offset_s: 0.1}", "Mocap"),  # the older per-stream key
    ],
)
@pytest.mark.parametrize("backend", ["sim", "emulated"])
def test_a_clock_for_a_stream_the_sim_has_not_is_one_line_naming_the_key_and_the_streams(
    clocks, key, backend, tmp_path
):
    from beambench.acquisition.streams import MOTOR
    from beambench.backends.sim_streams import SIM_STREAMS

    proto = tmp_path / "p.yaml"
    proto.write_text(BASE + f"sim: {{{clocks}}}\n")
    line = one_line_error(*cli("run", str(proto), "--backend", backend, "--dry-run"), f"{proto}: sim.clocks")
    assert repr(key) in line, line
    assert f"streams: {', '.join([MOTOR, *SIM_STREAMS])})" in line, line  # every registered stream, by name
    assert "pattern" not in line, line


@pytest.mark.parametrize(
    ("rig", "sim", "field"),
    [
        ("walker", "{thermal_drift: {tau_s: 50}}", "sim.thermal_drift"),  # another scene's option
        ("contact", "{model: auto, tolerance_mm: 0.00001}", "sim.tolerance_mm"),  # a tolerance nothing meets
        ("contact", "{clocks: {laser: {drift_ppm: 5}}}", "sim.clocks.laser"),
    ],
)
def test_a_simulation_the_rig_cannot_make_is_one_line_naming_the_protocols_file(rig, sim, field, tmp_path):
    proto = tmp_path / "p.yaml"
    proto.write_text(f"rig: {rig}\nsweep: {{frequencies: [20, 25]}}\nsettle_s: 0.1\nrecord_s: 0.1\nsim: {sim}\n")
    line = one_line_error(*cli("run", str(proto), "--dry-run"), field)
    assert line.startswith(f"beambench: error: {proto}: {field}"), line
