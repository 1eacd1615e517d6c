"""Hostile input through the real CLI: one line naming the field, exit 2, no traceback, nothing written.

Duplicate YAML keys, vanishing frequencies, sizes that would be allocated before a refusal, a protocol's
``rig_file:``, names that are not one path component, parameter sets outside physical bounds, numbers that are
not numbers on the command line.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from beambench.common.yaml_config import ConfigError, parse_yaml
from conftest import cli, one_line_error, skip_unless_ci, unwritable_folder, wait_until

BASE = "name: t\nsweep: {frequencies: [5, 10]}\nsettle_s: 0.2\nrecord_s: 0.3\n"


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

    from beambench.acquisition.protocol.schema import format_name

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


# --- parameter sets: validated like protocols, physics that diverges stops the run ---------------------------
@pytest.mark.parametrize(
    ("body", "field"),
    [
        ("beam: {k: 1e300}", "beam.k"),
        ("beam: {k_twist: -1}", "beam.k_twist"),
        ("beam: {b_twist: -0.1}", "beam.b_twist"),
        ("beam: {material: {youngs_modulus: -5}}", "beam.material.youngs_modulus"),
        ("beam: {material: {density: 0}}", "beam.material.density"),
        ("beam: {material: {poisson: 0.9}}", "beam.material.poisson"),
        ("beam: {twist_deg: 1e9}", "beam.twist_deg"),
        ("rig: {friction: 'x'}", "rig.friction"),
        ("rig: {friction: [1]}", "rig.friction"),
        ("rig: {plate_gap: 1e300}", "rig.plate_gap"),
        ("rig: {contact_timeconst: -1}", "rig.contact_timeconst"),
        ("rig: {nosuch: 1}", "rig.nosuch"),
        ("rig: {plate_gap: true}", "rig.plate_gap"),
        ("rig: {sole_at_corner: 1}", "rig.sole_at_corner"),
        ("walker: {foot_mass: 'x'}", "walker.foot_mass"),
        ("walker: {timestep: 1e-12}", "walker.timestep"),
        ("walker: {nosuch: 1}", "walker.nosuch"),
        ("nosuch: 1", "nosuch"),
        ("name: [1]", "name"),
    ],
)
def test_a_parameter_set_outside_physical_bounds_is_refused_dry_run_and_run(tmp_path, body, field):
    params = tmp_path / "set.yaml"
    params.write_text(f"model: prb3\n{body}\n")
    proto = tmp_path / "p.yaml"
    proto.write_text(BASE + f"sim: {{params: '{params}'}}\n")
    out = tmp_path / "out"
    for extra in (["--dry-run"], ["--out", str(out), "--rerun", "save"]):
        code, res = cli("run", str(proto), *extra)
        one_line_error(code, res, "sim.params", field)
    assert not out.exists()


def test_every_shipped_parameter_set_is_inside_the_physical_bounds():
    from beambench.sim.models.params import SIM_BACKEND_DIR, load_params

    shipped = sorted(SIM_BACKEND_DIR.glob("*.yaml"))
    assert shipped
    for f in shipped:
        assert load_params(str(f), model=f.stem.split("_")[0]).length > 0


def test_a_run_whose_physics_diverges_stops_with_one_line_motor_idle_session_saved(tmp_path):
    """Stiff springs on a near-massless beam at a 10 ms explicit-Euler step: MuJoCo's bad-QACC reset."""
    import h5py

    from beambench.sinks.session_file.reader import read_session

    params = tmp_path / "stiff.yaml"
    params.write_text("model: prb3\nbeam: {k: 100, k_twist: 100, b: 1.0e-6, b_twist: 0, mass: 1.0e-4}\n")
    proto = tmp_path / "p.yaml"
    proto.write_text(
        "name: t\nsweep: {frequencies: [40, 40, 40]}\nsettle_s: 0.5\nrecord_s: 0.5\n"
        f"sim: {{params: '{params}', timestep: 0.01, integrator: euler}}\n"
    )
    code, res = cli("run", str(proto), "--out", str(tmp_path / "out"), "--rerun", "off", "--name", "div")
    assert code == 1, res
    faults = [ln for ln in res.splitlines() if ln.startswith("beambench:")]
    assert len(faults) == 1 and "diverged" in faults[0], res
    assert "WARNING" not in res and "Nan" not in res.replace(faults[0], ""), res
    session = read_session(tmp_path / "out" / "div.h5")
    kinds = list(session.events["kind"])
    assert "idle" in kinds and kinds.index("idle") > kinds.index("start"), kinds
    assert len(session.steps) < 3
    with h5py.File(tmp_path / "out" / "div.h5") as f:
        assert "general" in f


# --- the Rerun viewer listens on loopback only ------------------------------------------------------------
def _listening_addresses(pid: int) -> list[str]:
    import psutil

    return [c.laddr.ip for c in psutil.Process(pid).net_connections(kind="inet") if c.status == psutil.CONN_LISTEN]


@pytest.fixture
def xvfb_display(tmp_path):
    """A private X server for a windowed viewer (no display on CI)."""
    import shutil
    import subprocess

    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed")
    for n in range(140, 200):
        if not Path(f"/tmp/.X11-unix/X{n}").exists() and not Path(f"/tmp/.X{n}-lock").exists():
            break
    proc = subprocess.Popen(
        ["Xvfb", f":{n}", "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )

    def listening() -> bool:
        assert proc.poll() is None, "Xvfb exited"
        return Path(f"/tmp/.X11-unix/X{n}").exists()

    try:
        wait_until(listening, 30, "Xvfb to start", 0.05)
        yield f":{n}"
    finally:
        proc.kill()
        proc.wait()


def test_a_spawned_viewer_listens_on_loopback_only(xvfb_display, monkeypatch):
    import socket

    from beambench.sinks.viewer.spawn import rerun_binary, spawn_viewer

    if rerun_binary() is None:
        pytest.skip("the rerun viewer binary is missing")
    monkeypatch.setenv("DISPLAY", xvfb_display)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = spawn_viewer(port)
    assert proc is not None
    try:
        addresses = _listening_addresses(proc.pid)
        assert addresses, "the viewer listens nowhere"
        assert all(a in ("127.0.0.1", "::1") for a in addresses), addresses
        assert spawn_viewer(port) is None  # a viewer already listening is reused, as rr.spawn does
    finally:
        proc.kill()
        proc.wait()


def test_a_viewer_that_exits_at_start_is_one_line_with_its_own_reason():
    """The viewer's own last line (here: a memory limit it cannot read) is the error, not a guess."""
    import socket

    from beambench.sinks.viewer.spawn import ViewerStartError, rerun_binary, spawn_viewer

    if rerun_binary() is None:
        skip_unless_ci("the rerun viewer binary is missing")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(ViewerStartError) as err:
        spawn_viewer(port, memory_limit="bogus")
    line = str(err.value)
    assert line.startswith("the Rerun viewer exited at start (status ") and "\n" not in line, line
    assert "bogus" in line and "memory-limit" in line and "\x1b" not in line, line


def test_the_headless_viewer_listens_on_loopback_only():
    """The viewer process it starts (this process's new child, listening on the viewer's port) listens on
    loopback only, on every port it opens."""
    import psutil

    from beambench.session.viewer import HeadlessViewer, ViewerUnavailable, vulkan_available

    if not vulkan_available():
        skip_unless_ci("no Vulkan driver for the headless viewer")
    me = psutil.Process()
    before = {p.pid for p in me.children(recursive=True)}
    try:
        viewer = HeadlessViewer().__enter__()
    except ViewerUnavailable as exc:
        skip_unless_ci(str(exc))
    try:
        spawned = [p for p in me.children(recursive=True) if p.pid not in before]
        assert len(spawned) == 1, spawned
        connections = spawned[0].net_connections(kind="inet")
        assert viewer.port in {c.laddr.port for c in connections if c.status == psutil.CONN_LISTEN}
        addresses = _listening_addresses(spawned[0].pid)
        assert addresses and all(a in ("127.0.0.1", "::1") for a in addresses), addresses
    finally:
        viewer.__exit__(None, None, None)


def test_spawn_without_the_viewer_binary_is_one_line(tmp_path):
    """A rerun_cli package without its binary and no ``rerun`` on PATH: one warning line, the run goes on."""
    import os
    import subprocess
    import sys

    fake = tmp_path / "site" / "rerun_cli"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("")
    proto = tmp_path / "p.yaml"
    proto.write_text("name: t\nsweep: {frequencies: [5]}\nsettle_s: 0.1\nrecord_s: 0.1\n")
    path = os.pathsep.join(p for p in (str(tmp_path / "site"), os.environ.get("PYTHONPATH", "")) if p)
    env = dict(os.environ, PATH="/usr/bin:/bin", PYTHONPATH=path)
    env.pop("DISPLAY", None)
    res = subprocess.run(
        [sys.executable, "-m", "beambench", "run", str(proto), "--out", str(tmp_path / "o"), "--rerun", "spawn"],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    said = [ln for ln in res.stderr.splitlines() if ln.startswith("beambench:")]
    assert len(said) == 1 and "viewer binary was not found" in said[0], res.stderr
    others = [ln for ln in res.stderr.splitlines() if ln.strip() and ln not in said]
    assert all("step" in ln or "starting" in ln for ln in others), res.stderr  # progress lines only


# --- device text reaches the terminal without control sequences ---------------------------------------------
HOSTILE = "Motive\x1b]52;c;cm0gLXJmIH4=\x07\x1b]0;pwned\x1b\\\x1b[2J\x9d0;t\x9c\u202etxt\x07\x7f"


@pytest.mark.parametrize(
    ("raw", "shown"),
    [
        (HOSTILE, "Motivetxt"),
        ("a\x1b[31mred\x1b[0m b", "ared b"),
        ("line\nbreak\ttab\rcr", "line break tab cr"),
        ("ok é 中 ✓", "ok é 中 ✓"),
        ("\x1bP1$r\x1b\\x\x1bc", "x"),
    ],
)
def test_printable_strips_escape_sequences_and_controls(raw, shown):
    from beambench.common.text import printable

    assert printable(raw) == shown


def test_natnet_decode_prints_no_escape_sequence_a_server_sent(tmp_path):
    from beambench.devices.natnet import frame as nf
    from beambench.devices.natnet import protocol as nn
    from beambench.devices.natnet import wire as nw
    from test_natnet_capture import write_pcap

    sender = nn.Sender(HOSTILE, nw.Version(3, 1, 0, 0), nw.V4_1)
    info = nn.ServerInfo(sender, 1_000_000, 1511, True, "239.255.42.99")
    frame = nf.FrameOfData(7, timestamp=0.1, mid_exposure=1, data_received=2, transmit=3)
    path = tmp_path / "hostile.pcap"
    write_pcap(path, [(1.0, nn.encode(info), 1510, 50000), (1.1, nn.encode(frame, (4, 1)), 1511, 50000)])
    code, out = cli("natnet", "decode", str(path), "--out", str(tmp_path / "f.csv"))
    assert code == 0, out
    assert "SERVERINFO: Motive" in out, out
    assert not any(c in out for c in "\x1b\x07\x9d\x9c\x7f\u202e"), repr(out)


# --- numbers on the command line, output paths ---------------------------------------------------------------
@pytest.fixture(scope="module")
def short_session(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("session")
    proto = folder / "p.yaml"
    proto.write_text("name: t\nsweep: {frequencies: [5]}\nsettle_s: 0.1\nrecord_s: 0.2\n")
    code, out = cli("run", str(proto), "--out", str(folder), "--name", "s", "--rerun", "off")
    assert code == 0, out
    proto.unlink()
    return folder / "s.h5"


@pytest.mark.parametrize("value", ["nan", "inf", "5,-inf", "1e-320x"])
def test_analyze_force_at_must_be_finite(short_session, value):
    before = tree(short_session.parent)
    code, out = cli("analyze", str(short_session), "--force-at", value)
    one_line_error(code, out, "--force-at")
    assert tree(short_session.parent) == before


@pytest.mark.parametrize("loads", ["nan,0", "1,inf", "0,-nan"])
def test_calibrate_loadcells_loads_must_be_finite(tmp_path, loads):
    code, out = cli("calibrate", "loadcells", "--emulate", "--yes", "--loads", loads, "--out", str(tmp_path / "c.yaml"))
    one_line_error(code, out, "--loads")
    assert tree(tmp_path) == []


@pytest.mark.parametrize("where", ["missing", "unwritable"])
def test_view_out_in_a_folder_that_takes_no_file_is_one_line(short_session, tmp_path, where):
    folder = tmp_path / "nonexistent" if where == "missing" else unwritable_folder(tmp_path)
    before = tree(short_session.parent)
    code, out = cli("view", str(short_session), "--rerun", "save", "--out", str(folder / "x.rrd"))
    one_line_error(code, out, "--out")
    code, out = cli("view", str(short_session), "--screenshot", str(folder / "x.png"))
    one_line_error(code, out, "screenshot")
    assert tree(short_session.parent) == before


def test_a_dangling_symlink_named_like_the_session_leaves_no_empty_recording(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "s.h5").symlink_to(tmp_path / "nowhere.h5")
    proto = tmp_path / "p.yaml"
    proto.write_text("name: t\nsweep: {frequencies: [5]}\nsettle_s: 0.1\nrecord_s: 0.1\n")
    code, res = cli("run", str(proto), "--out", str(out), "--name", "s", "--rerun", "save")
    assert code == 0, res
    assert not (out / "s.rrd").exists()
    assert (out / "s_1.h5").is_file() and (out / "s_1.rrd").stat().st_size > 0
    assert not (tmp_path / "nowhere.h5").exists()


def test_a_run_result_quoting_a_device_prints_no_escape_sequence(tmp_path, capsys):
    import typer

    from beambench.commands.run import report_run

    with pytest.raises(typer.Exit) as stop:
        report_run("fault", f"device fault: load cells said {HOSTILE}", tmp_path / "s.h5", False, [HOSTILE])
    assert stop.value.exit_code == 1
    err = capsys.readouterr().err
    assert "load cells said Motivetxt" in err and "also Motivetxt" in err, err
    assert not any(c in err for c in "\x1b\x07\x9d\x9c\x7f\u202e"), repr(err)
