"""Fuzzing protocol files: whatever the text, the only outcomes are a valid Protocol or a ConfigError, quickly."""

from __future__ import annotations

import time

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from beambench.acquisition.protocol.plan import plan, summary
from beambench.acquisition.protocol.schema import ConfigError, Protocol, parse_protocol
from conftest import fuzz_examples

VALID = """
name: fuzz
rig: contact
sweep: {start: 1, stop: 40, step: 1}
settle_s: 2.0
record_s: 5.0
amplitude_mm: 2.0
limits: {max_frequency_hz: 40, max_current_a: 10, max_amplitude_mm: 3}
sim: {model: prb3, params: paper, plate_gap_mm: 5.5, twist_deg: 90, noise: true, seed: 0}
output: {name: "{protocol}_{backend}_{date}"}
"""
BOUND_S = 2.0  # each parse, however hostile the input (a bound, not a benchmark)

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=30),
)
values = st.recursive(
    scalars, lambda c: st.lists(c, max_size=5) | st.dictionaries(st.text(max_size=10), c, max_size=5), max_leaves=20
)
FIELDS = [
    "name",
    "rig",
    "backend",
    "sweep",
    "settle_s",
    "record_s",
    "amplitude_mm",
    "limits",
    "sim",
    "output",
    "monitors",
    "release",
    "description",
    "rig_file",
]
SUBFIELDS = {
    "sweep": ["start", "stop", "step", "frequencies"],
    "sim": ["model", "params", "timestep", "seed", "twist_deg", "plate_gap_mm", "noise", "mocap_clock", "clocks"],
    "limits": ["max_frequency_hz", "max_current_a", "max_amplitude_mm"],
    "output": ["name"],
}


def _outcome(text: str) -> None:
    t0 = time.perf_counter()
    try:
        p = parse_protocol(text, "fuzz.yaml")
    except ConfigError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 700
    else:
        assert isinstance(p, Protocol)
        s = summary(p, "sim")  # a valid protocol plans without surprises
        assert s["steps"] == len(plan(p)) >= 1
    assert time.perf_counter() - t0 < BOUND_S


@settings(max_examples=fuzz_examples(150), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.text(max_size=400))
def test_random_text(text):
    _outcome(text)


@settings(max_examples=fuzz_examples(100), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=300))
def test_random_bytes_decoded_loosely(data):
    _outcome(data.decode("utf-8", "replace"))


@settings(max_examples=fuzz_examples(200), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(FIELDS), st.data())
def test_mutated_valid_protocol(field, data):
    doc = yaml.safe_load(VALID)
    if field in SUBFIELDS and data.draw(st.booleans()):
        sub = data.draw(st.sampled_from(SUBFIELDS[field]))
        doc.setdefault(field, {})[sub] = data.draw(values)
    elif data.draw(st.booleans()):
        doc[field] = data.draw(values)
    else:
        doc.pop(field, None)
    _outcome(yaml.safe_dump(doc))


@settings(max_examples=fuzz_examples(150), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(min_value=0, max_value=len(VALID)), st.text(max_size=20))
def test_spliced_text(pos, insert):
    _outcome(VALID[:pos] + insert + VALID[pos:])
