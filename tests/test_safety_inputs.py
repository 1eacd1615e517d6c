"""Bad input never gets in, never hangs, never overwrites, and always ends in one line with exit code 2.

Checked here: session names and exclusive creation, truncated sessions, size caps, finite numbers and booleans,
tracebacks turned into one line, the model and parameter set (dry run included) and the wrong kind of file.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import pytest

from beambench.acquisition.protocol.plan import session_path
from beambench.acquisition.protocol.schema import load_protocol, parse_protocol
from beambench.common.yaml_config import MAX_FILE_BYTES, ConfigError, parse_yaml
from beambench.sim.models.params import ParamsError, params_from_dict
from beambench.sinks.session_file.reader import SessionFileError, read_session
from beambench.sinks.session_file.writer import SessionWriter
from beambench.studies.sweep.run import SweepError, load_sweep
from conftest import cli, one_line_error

ROOT = Path(__file__).resolve().parents[1]
PROTOCOLS = ROOT / "protocols"
BASE = "name: t\nsweep: {frequencies: [5, 10]}\nsettle_s: 0.2\nrecord_s: 0.3\n"


# --- point 7: finite numbers, booleans are not numbers ---------------------------------------------------
@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("sweep: {frequencies: [.nan, 100]}", "sweep.frequencies.0"),
        ("sweep: {frequencies: [5, .inf]}", "sweep.frequencies.1"),
        ("sweep: {frequencies: [true]}", "sweep.frequencies.0"),
        ("sweep: {start: 1, stop: .inf, step: 1}", "sweep.stop"),
        ("sweep: {start: .nan, stop: 4, step: 1}", "sweep.start"),
        ("sweep: {frequencies: [5]}\nsim: {twist_deg: .nan}", "sim.twist_deg"),
        ("sweep: {frequencies: [5]}\namplitude_mm: .inf", "amplitude_mm"),
        ("sweep: {frequencies: [5]}\nsettle_s: false", "settle_s"),
        ("sweep: {frequencies: [5]}\nsim: {clocks: {mocap: {drift_ppm: .nan}}}", "sim.clocks.mocap.drift_ppm"),
        ("sweep: {frequencies: [5]}\nlimits: {max_frequency_hz: .nan}", "limits.max_frequency_hz"),
        ("sweep: {frequencies: ['5']}", "sweep.frequencies.0"),
    ],
)
def test_non_finite_and_boolean_numbers_are_rejected(text, field):
    with pytest.raises(ConfigError) as exc:
        parse_protocol(text, "p.yaml")
    assert exc.value.field == field, str(exc.value)


def test_a_rig_file_rejects_non_finite_numbers(tmp_path):
    from beambench.acquisition.protocol.schema import load_rig_file

    rig = tmp_path / "rig.yaml"
    rig.write_text("odrive: {watchdog_timeout_s: .nan}\n")
    with pytest.raises(ConfigError, match=r"odrive\.watchdog_timeout_s"):
        load_rig_file(rig)
    rig.write_text("odrive: {node_id: true}\n")
    with pytest.raises(ConfigError, match=r"odrive\.node_id"):
        load_rig_file(rig)


def test_parameter_sets_reject_non_finite_and_boolean_numbers():
    for beam in ({"k": float("nan")}, {"k": True}, {"material": {"density": float("inf")}}, {"k": "x"}):
        with pytest.raises(ParamsError):
            params_from_dict({"beam": beam}, "p.yaml")
    assert params_from_dict({"beam": {"k": 0.5}}).k == 0.5


def test_yaml_1_2_exponents_are_numbers():
    assert parse_yaml("a: 26.0e6\nb: 1e-4\n", "x") == {"a": 26.0e6, "b": 1e-4}


def test_a_frequency_over_the_limit_in_a_list_is_caught_in_a_dry_run(tmp_path):
    proto = tmp_path / "p.yaml"
    proto.write_text("name: t\nsweep: {frequencies: [5, 100, 10]}\nlimits: {max_frequency_hz: 40}\n")
    code, out = cli("run", str(proto), "--dry-run")
    one_line_error(code, out, "sweep = 100", "max_frequency_hz")


# --- point 4: caps ------------------------------------------------------------------------------------
def test_a_tiny_sweep_step_is_refused_quickly_run_and_dry_run(tmp_path):
    proto = tmp_path / "p.yaml"
    proto.write_text("name: t\nsweep: {start: 1, stop: 40, step: 1.0e-9}\n")
    for extra in ([], ["--dry-run"]):
        t0 = time.perf_counter()
        code, out = cli("run", str(proto), "--out", str(tmp_path), *extra)
        one_line_error(code, out, "steps", "10000")
        assert time.perf_counter() - t0 < 20  # a bound, not a benchmark: it used to spin for hours


def test_an_alias_bomb_is_refused_and_not_echoed(tmp_path):
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for i in range(1, 9):
        prev, cur = chr(96 + i), chr(97 + i)
        lines.append(f"{cur}: &{cur} [" + ",".join([f"*{prev}"] * 9) + "]")
    text = "\n".join(lines) + "\ndescription: *i\nsweep: {frequencies: [5]}\n"
    with pytest.raises(ConfigError) as exc:
        parse_protocol(text, "bomb.yaml")
    assert "expands" in str(exc.value) and len(str(exc.value)) < 200


def test_deep_nesting_and_huge_files_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="nested deeper"):
        parse_protocol("sweep: {frequencies: [5]}\ndescription: " + "[" * 100_000 + "]" * 100_000, "deep.yaml")
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * MAX_FILE_BYTES + "\n" + BASE)
    with pytest.raises(ConfigError, match="larger than"):
        load_protocol(big)


def test_a_huge_value_is_never_echoed_in_full():
    with pytest.raises(ConfigError) as exc:
        parse_protocol("sweep: {frequencies: [5]}\nsettle_s: [" + ", ".join(["1"] * 50_000) + "]", "p.yaml")
    assert len(str(exc.value)) < 300


@pytest.mark.parametrize("model", ["rod100000", "rod0", "rod99x", "beam", "prb4"])
def test_a_bad_sim_model_is_one_line_blaming_sim_model_dry_run_too(tmp_path, model):
    proto = tmp_path / "p.yaml"
    proto.write_text(BASE + f"sim: {{model: {model}}}\n")
    for extra in (["--dry-run"], ["--out", str(tmp_path), "--rerun", "off"]):
        code, out = cli("run", str(proto), *extra)
        one_line_error(code, out, "sim.model", model)
    assert not list(tmp_path.glob("*.h5"))  # nothing ran


@pytest.mark.parametrize("params", ["nosuch", "../../etc/passwd", "x" * 300])
def test_a_missing_parameter_set_is_one_line_dry_run_too(tmp_path, params):
    proto = tmp_path / "p.yaml"
    proto.write_text(BASE + f"sim: {{params: '{params}'}}\n")
    for extra in (["--dry-run"], ["--out", str(tmp_path), "--rerun", "off"]):
        code, out = cli("run", str(proto), *extra)
        one_line_error(code, out, "sim.params")


def test_a_malformed_parameter_file_is_one_line(tmp_path):
    params = tmp_path / "bad.yaml"
    params.write_text("beam: {k: .nan}\n")
    proto = tmp_path / "p.yaml"
    proto.write_text(BASE + f"sim: {{params: '{params}'}}\n")
    code, out = cli("run", str(proto), "--dry-run")
    one_line_error(code, out, "sim.params", "finite")


def test_sweep_files_are_capped_too(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("name: s\nscene: free_beam\ngrid: {twist_deg: {start: 0, stop: 180, step: 1.0e-9}}\n")
    with pytest.raises(SweepError, match="more than"):
        load_sweep(f)
    f.write_text("name: s\nscene: free_beam\nfrequencies: [.nan]\n")
    with pytest.raises(SweepError, match="finite"):
        load_sweep(f)
    f.write_text("name: s\nscene: free_beam\nbase: {model: rod100000}\n")
    with pytest.raises(SweepError, match="segments"):
        load_sweep(f)


# --- point 2: names and exclusive creation -----------------------------------------------------------
@pytest.mark.parametrize(
    "name", ["a\x00b", "a/b", "..", ".", "x" * 300, "tab\there", "nl\nx", "back\\slash", "é" * 150]
)
def test_bad_session_names_are_refused(tmp_path, name):
    protocol = parse_protocol(BASE)
    with pytest.raises(ConfigError):
        session_path(protocol, "sim", tmp_path, name)


@pytest.mark.parametrize("template", ["{protocol.nosuch}", "{date:>100000}", "{0}", "{nosuch}", "{date!x}", "a\\0b"])
def test_bad_name_templates_are_one_line_config_errors(template):
    with pytest.raises(ConfigError) as exc:
        parse_protocol(BASE + f'output: {{name: "{template}"}}\n', "p.yaml")
    assert exc.value.field == "output.name" and "\n" not in str(exc.value)


def test_a_nul_in_the_name_cannot_overwrite_an_existing_session(tmp_path):
    existing = tmp_path / "keep.h5"
    with h5py.File(existing, "w") as f:
        f.attrs["mine"] = 1
    proto = tmp_path / "p.yaml"
    proto.write_text(BASE)
    code, out = cli("run", str(proto), "--out", str(tmp_path), "--name", "keep\x00x", "--rerun", "off")
    one_line_error(code, out, "--name")
    with h5py.File(existing, "r") as f:
        assert f.attrs["mine"] == 1


def test_the_session_writer_never_overwrites(tmp_path):
    path = tmp_path / "s.h5"
    path.write_bytes(b"precious")
    with pytest.raises(SessionFileError, match="exists"):
        SessionWriter(path, {}).open([])
    assert path.read_bytes() == b"precious"


def test_the_rrd_beside_a_session_is_never_overwritten(tmp_path):
    from beambench.session.run import run_session

    (tmp_path / "s.rrd").write_bytes(b"precious")
    protocol = parse_protocol(BASE)
    with pytest.raises(SessionFileError, match="never overwritten"):
        run_session(protocol, BASE, "sim", tmp_path / "s.h5", rerun_mode="save", show_progress=False)
    assert (tmp_path / "s.rrd").read_bytes() == b"precious"


# --- point 9: one line and exit 2 instead of a traceback ---------------------------------------------
def test_tracebacks_become_one_line(tmp_path):
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe" * 20)
    code, out = cli("run", str(binary), "--dry-run")
    one_line_error(code, out, "not a text file")

    for text, words in (
        (BASE + "sim: {seed: -1}\n", ["sim.seed"]),
        ("name: t\nsweep: {start: 1, stop: .inf, step: 1}\n", ["sweep.stop"]),
        ("name: " + "n" * 300 + "\nsweep: {frequencies: [5]}\n", ["name"]),
        (BASE + 'output: {name: "{protocol.nosuch}"}\n', ["output.name"]),
        (BASE + 'output: {name: "{date:>100000}"}\n', ["output.name"]),
    ):
        proto = tmp_path / "p.yaml"
        proto.write_text(text)
        code, out = cli("run", str(proto), "--out", str(tmp_path), "--rerun", "off")
        one_line_error(code, out, *words)

    proto = tmp_path / "p.yaml"
    proto.write_text(BASE)
    a_file = tmp_path / "afile"
    a_file.write_text("x")
    code, out = cli("run", str(proto), "--out", str(a_file), "--rerun", "off")
    one_line_error(code, out, "--out")
    code, out = cli("run", str(proto), "--out", str(a_file / "sub"), "--rerun", "off")
    one_line_error(code, out, "--out")
    code, out = cli("run", str(proto), "--name", "n" * 300, "--out", str(tmp_path), "--rerun", "off")
    one_line_error(code, out, "--name")
    code, out = cli("run", str(proto), "--backend", "emulated", "--can-log", str(tmp_path / "x.txt"), "--dry-run")
    one_line_error(code, out, "--can-log")


def test_an_unwritable_out_folder_is_one_line(tmp_path):
    """A folder nobody may write into: chmod 500 for a normal user; /proc refuses new folders even to root."""
    if os.geteuid() == 0:
        target = Path("/proc/self/beambench-out")
    else:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        target = ro / "x"
    proto = tmp_path / "p.yaml"
    proto.write_text(BASE)
    code, out = cli("run", str(proto), "--out", str(target), "--rerun", "off")
    one_line_error(code, out, "--out")


def test_an_unwritable_session_path_is_a_session_file_error(tmp_path):
    """Also as root: a session path whose folder cannot be made (a file sits where the folder should be)."""
    (tmp_path / "f").write_text("x")
    with pytest.raises(SessionFileError, match="cannot create"):
        SessionWriter(tmp_path / "f" / "s.h5", {}).open([])


# --- the wrong kind of file --------------------------------------------------------------------------
def test_a_sweep_file_given_to_run_says_so():
    code, out = cli("run", str(PROTOCOLS / "twist_sweep.yaml"), "--dry-run")
    one_line_error(code, out, "sweep file", "beambench sweep")


def test_a_protocol_file_given_to_sweep_says_so():
    code, out = cli("sweep", str(PROTOCOLS / "contact_sweep.yaml"))
    one_line_error(code, out, "protocol file", "beambench run")


def test_every_shipped_file_loads_with_its_own_command():
    """Each shipped file is a protocol (``beambench run``: steps to drive) or a sweep file (``beambench sweep``:
    scene points and frequencies), named as its file, and the other command refuses it with one line."""
    import yaml

    from beambench.acquisition.protocol.plan import plan

    files = sorted(PROTOCOLS.glob("*.yaml"))
    assert len(files) >= 6, files  # the shipped protocols and sweep files (README: "Shipped protocols")
    kinds = {}
    for f in files:
        if "scene" in yaml.safe_load(f.read_text()):  # a sweep file names its scene at the top level
            spec = load_sweep(f)
            assert spec.name == f.stem and spec.scene_points() and spec.frequency_values(), f
            with pytest.raises(ConfigError, match="this is a sweep file"):
                load_protocol(f)
            kinds[f.stem] = "sweep"
        else:
            protocol, _ = load_protocol(f)
            assert protocol.name == f.stem and plan(protocol), f
            with pytest.raises(SweepError, match="this is a protocol file"):
                load_sweep(f)
            kinds[f.stem] = "protocol"
    assert set(kinds.values()) == {"protocol", "sweep"}, kinds


# --- point 3: truncated and foreign session files ----------------------------------------------------
@pytest.fixture(scope="module")
def real_session(tmp_path_factory) -> Path:
    from beambench.session.run import run_session

    out = tmp_path_factory.mktemp("real")
    protocol = parse_protocol(BASE)
    run_session(protocol, BASE, "sim", out / "real.h5", rerun_mode="off", show_progress=False)
    return out / "real.h5"


def test_truncated_sessions_fail_fast_with_one_line(real_session, tmp_path):
    data = real_session.read_bytes()
    cuts = [0, 7, 100, 2048, len(data) // 4, len(data) // 2, len(data) - 1000, len(data) - 1]
    files = []
    for k in cuts:
        cut = tmp_path / f"cut{k}.h5"
        cut.write_bytes(data[:k])
        files.append(str(cut))
    for name, groups in (("noacq", ["general", "steps", "events"]), ("nosteps", ["general", "acquisition"])):
        with h5py.File(tmp_path / f"{name}.h5", "w") as f:
            for g in groups:
                f.create_group(g)
        files.append(str(tmp_path / f"{name}.h5"))
    not_hdf5 = tmp_path / "text.h5"
    not_hdf5.write_text("hello\n" * 100)
    files.append(str(not_hdf5))
    # every command on every file, in one child process with a time bound (a hang used to be forever)
    script = textwrap.dedent(
        """
        import json, sys
        from typer.testing import CliRunner
        from beambench.cli import app
        out = []
        for f in json.loads(sys.argv[1]):
            for args in (["analyze", f, "--out", f + "_report"], ["view", f, "--rerun", "save", "--out", f + ".rrd"],
                         ["fit", f, "--maxiter", "1", "--out", f + "_fit"]):
                r = CliRunner().invoke(app, args)
                exc = r.exception if r.exception is not None and not isinstance(r.exception, SystemExit) else None
                out.append([args[0], f, r.exit_code, r.output, repr(exc) if exc else None])
        print(json.dumps(out))
        """
    )
    env = dict(os.environ, PYTHONPATH=os.environ.get("PYTHONPATH") or str(ROOT / "src"))
    res = subprocess.run(
        [sys.executable, "-c", script, json.dumps(files)], capture_output=True, text=True, timeout=240, env=env
    )
    assert res.returncode == 0, res.stderr[-3000:]
    for cmd, f, code, output, exc in json.loads(res.stdout.strip().splitlines()[-1]):
        assert exc is None, f"{cmd} {f}: traceback {exc}"
        errors = [ln for ln in output.splitlines() if "error" in ln.lower()]
        assert code == 2 and len(errors) >= 1, f"{cmd} {f}: exit {code}: {output}"
        assert "Traceback" not in output


def test_read_session_raises_session_file_error_on_a_cut_copy(real_session, tmp_path):
    data = real_session.read_bytes()
    cut = tmp_path / "cut.h5"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(SessionFileError, match="truncated"):
        read_session(cut)
    assert len(read_session(real_session).steps) == 2  # the whole file still reads
