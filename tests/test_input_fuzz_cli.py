"""Junk protocol and parameter-set YAML through the real CLI (``run --dry-run``): the only outcomes are a dry run
(exit 0) or one ``beambench: error:`` line with exit 2; never a traceback, never a file written."""

from __future__ import annotations

import tempfile
from pathlib import Path

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from beambench.cli import app
from conftest import fuzz_examples

PROTOCOL = {
    "name": "fuzz",
    "sweep": {"frequencies": [5, 10]},
    "settle_s": 0.2,
    "record_s": 0.3,
    "limits": {"max_frequency_hz": 40},
    "sim": {"model": "prb3", "timestep": 2.0e-4},
    "output": {"name": "{protocol}_{date}"},
}
PARAMS = {
    "name": "fuzz",
    "model": "prb3",
    "beam": {"l2": 0.02366, "l3": 0.02634, "k": 0.34, "b": 0.0029, "mass": 0.00517, "material": {"density": 1210.0}},
    "rig": {"plate_gap": 0.0055, "friction": 0.5},
}
junk = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(
        [1e300, -1e300, 1e-320, 0.0, -0.0, -1.0, "", "x", "{protocol:>999999}", "../x", "a\nb", "\x1b]0;t"]
    ),
    st.text(max_size=12),
    st.lists(st.integers(), max_size=3),
    st.dictionaries(st.text(max_size=6), st.integers(), max_size=2),
)


def _mutate(doc: dict, data: st.DataObject) -> tuple[str, bool]:
    """``doc`` with one value (at any depth) replaced by junk, a key dropped or added, or a key given twice (then
    True: it must be refused)."""
    doc = yaml.safe_load(yaml.safe_dump(doc))
    node = doc
    while isinstance(node, dict) and node and data.draw(st.booleans()):
        key = data.draw(st.sampled_from(sorted(node)))
        if not isinstance(node[key], dict):
            break
        node = node[key]
    action = data.draw(st.sampled_from(["replace", "drop", "add", "repeat"]))
    key = data.draw(st.sampled_from(sorted(node))) if node else "x"
    if action == "replace":
        node[key] = data.draw(junk)
    elif action == "drop":
        node.pop(key, None)
    elif action == "add":
        node[data.draw(st.text(min_size=1, max_size=8))] = data.draw(junk)
    text = yaml.safe_dump(doc, allow_unicode=True)
    if action == "repeat":
        text += yaml.safe_dump({next(iter(doc)): data.draw(junk)})
    return text, action == "repeat"


def _dry_run(protocol_text: str, params_text: str | None = None, refuse: bool = False) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        proto = folder / "p.yaml"
        if params_text is not None:
            (folder / "set.yaml").write_text(params_text)
            protocol_text += f"\nsim: {{params: '{folder / 'set.yaml'}'}}\n"
        proto.write_text(protocol_text)
        res = CliRunner().invoke(app, ["run", str(proto), "--dry-run", "--out", str(folder / "out")])
        if res.exception is not None and not isinstance(res.exception, SystemExit):
            raise AssertionError(f"traceback: {res.exception!r}\n{protocol_text}\n{params_text}") from res.exception
        errors = [ln for ln in res.output.splitlines() if ln.startswith("beambench: error:")]
        assert res.exit_code in ((2,) if refuse else (0, 2)), res.output
        if res.exit_code == 2:
            assert len(errors) == 1 and len(errors[0]) < 700, res.output
        assert "Traceback" not in res.output
        if res.exit_code == 0 and params_text is not None:
            _assert_physical(yaml.safe_load(params_text))
        assert sorted(p.name for p in folder.iterdir()) in (["p.yaml"], ["p.yaml", "set.yaml"])


# What a printed beam on a bench can be (SI, low end excluded): centimetre links under a metre, a spring no
# stiffer than 100 N·m/rad and a damper under 10 N·m·s/rad (the paper's: 0.34 and 0.0029), grams not above 10 kg,
# a density between a foam's and osmium's (~22,600 kg/m³) with margin.
PHYSICAL_RANGES = {
    "l2": (0.0, 1.0),
    "l3": (0.0, 1.0),
    "k": (0.0, 100.0),
    "b": (0.0, 10.0),
    "mass": (0.0, 10.0),
    "material.density": (1.0, 1e5),
}


def _assert_physical(doc: dict) -> None:
    """A set a dry run accepted holds only finite numbers, each beam number inside its physical range
    (:data:`PHYSICAL_RANGES`: low end excluded, high end included)."""
    import math

    beam = dict(doc.get("beam") or {})
    numbers = {f"material.{k}": v for k, v in (beam.pop("material", None) or {}).items()} | beam
    for block in ("rig", "walker"):
        numbers |= {f"{block}.{k}": v for k, v in (doc.get(block) or {}).items()}
    for key, v in numbers.items():
        assert isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v), (key, v)
        if key in PHYSICAL_RANGES:
            low, high = PHYSICAL_RANGES[key]
            assert low < v <= high, (key, v, PHYSICAL_RANGES[key])


@settings(max_examples=fuzz_examples(150, 40), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_junk_protocols_are_a_dry_run_or_one_line(data):
    text, refuse = _mutate(PROTOCOL, data)
    _dry_run(text, refuse=refuse)


@settings(max_examples=fuzz_examples(150, 40), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_junk_parameter_sets_are_a_dry_run_or_one_line(data):
    base = {k: v for k, v in PROTOCOL.items() if k != "sim"}
    text, refuse = _mutate(PARAMS, data)
    _dry_run(yaml.safe_dump(base), text, refuse)


@settings(max_examples=fuzz_examples(100, 40), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.text(max_size=200))
def test_random_text_as_a_parameter_set_is_one_line(text):
    base = {k: v for k, v in PROTOCOL.items() if k != "sim"}
    _dry_run(yaml.safe_dump(base), text)
