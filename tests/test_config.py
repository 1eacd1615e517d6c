"""Protocol parsing: good files load, bad ones name the file, field, value and reason."""

from pathlib import Path

import pytest

from beambench.acquisition.protocol.plan import check_limits, plan, session_path, summary
from beambench.acquisition.protocol.schema import load_protocol, load_rig_file, parse_protocol
from beambench.common.yaml_config import ConfigError

ROOT = Path(__file__).resolve().parents[1]
GOOD = """
name: t
sweep: {start: 1, stop: 3, step: 1}
settle_s: 0.5
record_s: 0.5
"""


@pytest.mark.parametrize("name", ["contact_sweep", "walker_sweep"])
def test_shipped_protocols_load(name):
    p, text = load_protocol(ROOT / "protocols" / f"{name}.yaml")
    assert text.startswith("#")
    check_limits(p)
    assert p.sweep.values()[0] == 1.0


def test_contact_sweep_is_the_labs_sweep():
    p, _ = load_protocol(ROOT / "protocols" / "contact_sweep.yaml")
    steps = plan(p)
    assert [s.frequency_hz for s in steps] == [float(f) for f in range(1, 41)]
    assert summary(p, "sim")["total_duration_s"] == pytest.approx(280.0)
    assert p.amplitude_mm == 2.0


def test_explicit_frequency_list_and_fractional_steps():
    p = parse_protocol("sweep: {frequencies: [5, 2.5, 40]}\n")
    assert p.sweep.values() == [5.0, 2.5, 40.0]
    p = parse_protocol("sweep: {start: 1, stop: 2, step: 0.1}\n")
    assert len(p.sweep.values()) == 11 and p.sweep.values()[-1] == pytest.approx(2.0)


@pytest.mark.parametrize(
    "text, field, fragment",
    [
        ("sweep: {start: 1, stop: 3, step: 0}\n", "sweep.step", "greater than 0"),
        ("sweep: {start: 5, stop: 3, step: 1}\n", "sweep", "stop must be >= start"),
        ("sweep: {start: 1, stop: 3, step: 1}\nsettle_s: fast\n", "settle_s", "valid number"),
        ("sweep: {start: 1, stop: 3, step: 1}\nrig: boat\n", "rig", "'contact', 'walker'"),
        ("sweep: {start: 1, stop: 3, step: 1}\nfrequncy: 3\n", "frequncy", "unknown field"),
        ("rig: contact\n", "sweep", "Field required"),
        ("sweep: [1, 2\n", "line", "not valid YAML"),
    ],
)
def test_bad_protocol_names_field_and_reason(text, field, fragment):
    with pytest.raises(ConfigError) as info:
        parse_protocol(text, "bad.yaml")
    msg = str(info.value)
    assert msg.startswith("bad.yaml: ")
    assert field in msg and fragment in msg
    assert "\n" not in msg


def test_value_is_named():
    with pytest.raises(ConfigError) as info:
        parse_protocol("sweep: {start: 1, stop: 3, step: 1}\nsettle_s: fast\n", "p.yaml")
    assert "'fast'" in str(info.value)


def test_limit_violation_refused():
    p = parse_protocol("sweep: {frequencies: [10, 90]}\nlimits: {max_frequency_hz: 40}\n")
    with pytest.raises(ConfigError, match=r"sweep = 90.0: exceeds limits.max_frequency_hz = 40 Hz"):
        check_limits(p, "p.yaml")


def test_session_path_never_overwrites(tmp_path):
    p = parse_protocol(GOOD)
    first = session_path(p, "sim", tmp_path, "run")
    assert first == tmp_path / "run.h5"
    first.write_bytes(b"")
    assert session_path(p, "sim", tmp_path, "run") == tmp_path / "run_1.h5"
    auto = session_path(p, "sim", tmp_path)
    assert auto.name.startswith("t_sim_") and auto.suffix == ".h5"


@pytest.mark.parametrize(
    "text, field",
    [
        ("natnet: {markers: {Tip: [1, 2]}}\n", "natnet.markers.Tip"),  # a user's name, not a union branch
        ("natnet: {markers: {tip: [1, 2]}}\n", "natnet.markers.tip"),
        ("natnet: {markers: {Foot: 1.5}}\n", "natnet.markers.Foot"),
    ],
)
def test_a_capitalised_key_of_the_users_is_named_in_the_error(tmp_path, text, field):
    path = tmp_path / "rig.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_rig_file(path)
    assert f"rig.yaml: {field} = " in str(info.value)
