"""Hostile input through the real CLI: one line naming the field, exit 2, no traceback, nothing written.

Duplicate YAML keys, vanishing frequencies, sizes that would be allocated before a refusal, a protocol's
``rig_file:``, names that are not one path component, parameter sets outside physical bounds, numbers that are
not numbers on the command line.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from beambench.cli import app
from beambench.common.yaml_config import ConfigError, parse_yaml

BASE = "name: t\nsweep: {frequencies: [5, 10]}\nsettle_s: 0.2\nrecord_s: 0.3\n"


def cli(*args: str) -> tuple[int, str]:
    """Exit code and the combined output of one CLI call; a traceback fails the test."""
    res = CliRunner().invoke(app, list(args))
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise AssertionError(f"traceback instead of one line: {res.exception!r}") from res.exception
    return res.exit_code, res.output


def one_line_error(code: int, output: str, *words: str) -> str:
    """Exit 2 and exactly one ``beambench: error:`` line holding ``words``; no traceback."""
    errors = [ln for ln in output.splitlines() if ln.startswith("beambench: error:")]
    assert code == 2, output
    assert len(errors) == 1, output
    assert "Traceback" not in output, output
    assert len(errors[0]) < 400, errors[0]
    for w in words:
        assert w in errors[0], errors[0]
    return errors[0]


def tree(folder: Path) -> list[str]:
    """Every path under ``folder`` (to assert nothing was written)."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


# --- duplicate keys ---------------------------------------------------------------------------------------
def test_a_second_limits_block_is_refused_naming_the_key_and_line(tmp_path):
    proto = tmp_path / "p.yaml"
    proto.write_text(
        "name: t\nsweep: {frequencies: [150]}\nsettle_s: 0.2\nrecord_s: 0.3\n"
        "limits: {max_frequency_hz: 100}\nlimits: {max_frequency_hz: 200}\n"
    )
    code, out = cli("run", str(proto), "--dry-run")
    one_line_error(code, out, "duplicate key 'limits'", "line 6", "line 5")


@pytest.mark.parametrize(
    "text",
    [
        "a: 1\na: 2\n",
        "a: {b: 1, b: 2}\n",
        "a:\n  - {x: 1}\n  - {y: 1, y: 2}\n",
        "1: a\n1.0: b\n",
    ],
)
def test_duplicate_keys_are_refused_at_any_depth(text):
    with pytest.raises(ConfigError, match="duplicate key"):
        parse_yaml(text, "f.yaml")


def test_merge_keys_may_still_be_overridden():
    data = parse_yaml("base: &b {x: 1, y: 2}\nc: {<<: *b, y: 3}\n", "f.yaml")
    assert data["c"] == {"x": 1, "y": 3}


@pytest.mark.parametrize("kind", ["rig", "params", "sweep", "targets"])
def test_every_yaml_input_refuses_duplicate_keys(tmp_path, kind):
    f = tmp_path / f"{kind}.yaml"
    if kind == "rig":
        f.write_text("odrive: {node_id: 0}\nodrive: {node_id: 1}\n")
        proto = tmp_path / "p.yaml"
        proto.write_text(BASE)
        code, out = cli("run", str(proto), "--rig", str(f), "--dry-run")
    elif kind == "params":
        f.write_text("model: prb3\nbeam: {k: 0.3, k: 300}\n")
        proto = tmp_path / "p.yaml"
        proto.write_text(BASE + f"sim: {{params: '{f}'}}\n")
        code, out = cli("run", str(proto), "--dry-run")
    elif kind == "sweep":
        f.write_text("name: s\nscene: free_beam\nfrequencies: [5]\nfrequencies: [6]\n")
        code, out = cli("sweep", str(f), "--out", str(tmp_path / "out"))
    else:
        f.write_text("regimes: {}\nregimes: {}\n")
        code, out = cli("calibrate", "sim", "--targets", str(f), "--out", str(tmp_path / "out"))
    one_line_error(code, out, "duplicate key")
    assert not (tmp_path / "out").exists()


# --- vanishing frequencies, sizes before allocation ----------------------------------------------------------
@pytest.mark.parametrize(
    ("sweep", "field"),
    [
        ("{frequencies: [1e-320]}", "sweep.frequencies"),
        ("{frequencies: [5, 0.001]}", "sweep.frequencies"),
        ("{start: 1e-320, stop: 1e-320, step: 1}", "sweep.start"),
    ],
)
def test_a_vanishing_frequency_is_refused(tmp_path, sweep, field):
    proto = tmp_path / "p.yaml"
    proto.write_text(f"name: t\nsweep: {sweep}\nsettle_s: 0.2\nrecord_s: 0.3\n")
    code, out = cli("run", str(proto), "--dry-run")
    one_line_error(code, out, field)


def test_a_tiny_timestep_is_refused_before_anything_is_allocated(tmp_path):
    proto = tmp_path / "p.yaml"
    proto.write_text(BASE + "sim: {timestep: 1e-12}\n")
    code, out = cli("run", str(proto), "--dry-run")
    one_line_error(code, out, "sim.timestep")


def test_a_timestep_too_fine_for_the_run_length_is_refused(tmp_path):
    proto = tmp_path / "p.yaml"
    proto.write_text("name: t\nsweep: {start: 1, stop: 40, step: 1}\nsettle_s: 600\nrecord_s: 3600\n")
    proto.write_text(proto.read_text() + "sim: {timestep: 1e-6}\n")
    code, out = cli("run", str(proto), "--dry-run")
    one_line_error(code, out, "physics steps")


@pytest.mark.parametrize("template", ["{protocol:>300000000}", "{protocol:>99999999999}", "{date:{protocol}}"])
def test_a_huge_format_width_is_refused_before_formatting(tmp_path, template):
    proto = tmp_path / "p.yaml"
    proto.write_text(BASE + f'output: {{name: "{template}"}}\n')
    code, out = cli("run", str(proto), "--dry-run")
    one_line_error(code, out, "output.name")


def test_a_format_width_is_bounded_before_any_string_is_built():
    """``{protocol:>300000000}`` once built a 300 MB string (29 s) before refusing the name it made."""
    import tracemalloc

    from beambench.acquisition.config import format_name

    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match="width"):
            format_name("{protocol:>300000000}", "p", "contact", "sim", "20260101-000000")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1_000_000, peak


# --- rig_file in a protocol -------------------------------------------------------------------------------
def test_a_protocols_rig_file_is_read_relative_to_the_protocol(tmp_path):
    (tmp_path / "rig.yaml").write_text("odrive: {watchdog_timeout_s: .nan}\n")
    proto = tmp_path / "p.yaml"
    proto.write_text(BASE + "rig_file: rig.yaml\n")
    code, out = cli("run", str(proto), "--dry-run")
    one_line_error(code, out, "rig_file", "odrive.watchdog_timeout_s")
    proto.write_text(BASE + "rig_file: nosuch.yaml\n")
    code, out = cli("run", str(proto), "--dry-run")
    one_line_error(code, out, "rig_file", "nosuch.yaml")
    (tmp_path / "rig.yaml").write_text("odrive: {watchdog_timeout_s: 0.5}\n")
    proto.write_text(BASE + "rig_file: rig.yaml\n")
    code, out = cli("run", str(proto), "--dry-run")
    assert code == 0, out


def test_the_rig_option_wins_over_the_protocols_rig_file(tmp_path):
    (tmp_path / "good.yaml").write_text("odrive: {watchdog_timeout_s: 0.5}\n")
    proto = tmp_path / "p.yaml"
    proto.write_text(BASE + "rig_file: nosuch.yaml\n")
    code, out = cli("run", str(proto), "--rig", str(tmp_path / "good.yaml"), "--dry-run")
    assert code == 0, out


# --- names are one path component --------------------------------------------------------------------------
BAD_NAMES = ["/abs/path", "../../escaped", "a\nb", "", "..", "a/b", "esc\x1b[31m"]


@pytest.mark.parametrize("name", BAD_NAMES)
def test_calibrate_sim_name_is_checked_before_anything_is_written(tmp_path, name):
    out = tmp_path / "deep" / "out"
    code, res = cli(
        "calibrate", "sim", "--targets", "paper_contact_targets", "--out", str(out), "--name", name, "--quick"
    )
    one_line_error(code, res, "--name")
    assert tree(tmp_path) == []


@pytest.mark.parametrize("name", BAD_NAMES)
def test_fit_name_is_checked_before_anything_is_written(tmp_path, name):
    session = tmp_path / "s.h5"
    session.write_bytes(b"not read")
    params = tmp_path / "params"
    code, res = cli("fit", str(session), "--name", name, "--params-dir", str(params))
    one_line_error(code, res, "--name")
    assert tree(tmp_path) == ["s.h5"]


@pytest.mark.parametrize("model", ["", " , "])
def test_fit_without_a_model_is_one_line(tmp_path, model):
    session = tmp_path / "s.h5"
    session.write_bytes(b"not read")
    code, res = cli("fit", str(session), "--model", model)
    one_line_error(code, res, "--model")
    assert tree(tmp_path) == ["s.h5"]


def test_calibrate_sim_workers_are_bounded(tmp_path):
    code, res = cli(
        "calibrate", "sim", "--targets", "paper_contact_targets", "--out", str(tmp_path / "o"), "--workers", "100000"
    )
    one_line_error(code, res, "--workers", "256")
    assert tree(tmp_path) == []
