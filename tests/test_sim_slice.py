"""One simulation slice per protocol: the sim backend's run and the twin calibration simulate the same thing."""

from __future__ import annotations

import dataclasses

import pytest

from beambench.acquisition.protocol.schema import parse_protocol
from beambench.backends.sim import build_scene
from beambench.common.resources import shipped_dir
from beambench.common.yaml_config import ConfigError
from beambench.session.slices import sim_slice
from beambench.studies.twin_calibration import get_rig
from beambench.studies.twin_calibration.rig import parse_targets
from beambench.studies.twin_calibration.targets import CalibrationInputError, Targets

TARGETS = {  # inside every shipped sweep, so the calibration's written sweep is the protocol's own
    "contact": {"rig": "contact", "half_at_hz": 30, "third_at_hz": 32},
    "walker": {"rig": "walker", "speed_mm_s": {23: -35.7, 65: 156.3}},
}


def _shipped() -> list[tuple[str, str]]:
    """(name, text) of every shipped protocol a calibration rig can fit, plus the contact sweep with ``auto``."""
    out = []
    for path in sorted(shipped_dir("protocols").glob("*.yaml")):
        text = path.read_text()
        try:
            rig = parse_protocol(text).rig
        except ConfigError:  # a sweep file (beambench sweep), not a protocol
            continue
        if rig in TARGETS:
            out.append((path.name, text))
    contact = (shipped_dir("protocols") / "contact_sweep.yaml").read_text()
    auto = contact.replace("model: rod5g", "model: auto").replace("params: physical", "params: contact_paper")
    return [*out, ("contact_sweep auto", auto)]


def _targets(rig: str, text: str) -> Targets:
    return dataclasses.replace(parse_targets(TARGETS[rig], "t.yaml"), protocol_text=text)


@pytest.mark.parametrize(("name", "text"), _shipped(), ids=[n for n, _ in _shipped()])
def test_the_run_and_the_calibration_simulate_the_same_model_with_the_same_settings(name: str, text: str) -> None:
    proto = parse_protocol(text)
    run = build_scene(sim_slice(proto)).identity()
    base = get_rig(proto.rig).base(_targets(proto.rig, text))
    assert (base.model, base.params) == (run["model"], proto.sim.params)
    assert base.sim.integrator == run["integrator"]  # auto: the measured plan's (euler), not the protocol's default
    assert base.sim.twist_deg == run["twist_deg"]
    assert base.sim == sim_slice(proto).settings
    if proto.rig == "contact":
        assert base.sim.amplitude_m == run["amplitude_m"]
        assert (base.sim.settle_s, base.sim.record_s) == (proto.settle_s, proto.record_s)
        assert (base.sim.noise, base.sim.seed) == (proto.sim.noise, proto.sim.seed)
        assert base.frequencies == tuple(proto.sweep.values())  # type: ignore[union-attr]


def test_auto_picks_a_model_from_the_table_for_the_run_and_the_calibration_alike() -> None:
    """``auto`` is the measured plan's model and integrator in both (the calibration once took prb3 and the
    protocol's integrator by hand)."""
    text = _shipped()[-1][1]
    s = sim_slice(parse_protocol(text))
    assert s.plan is not None and (s.model, s.integrator) == (s.plan.model, s.plan.integrator)
    base = get_rig("contact").base(_targets("contact", text))
    assert (base.model, base.sim.integrator) == (s.plan.model, s.plan.integrator)


def test_a_walker_protocol_the_run_refuses_is_refused_by_the_calibration_too() -> None:
    """The run refuses ``auto`` on the walker (no measured table); the calibration says the same instead of
    quietly fitting prb3."""
    text = (shipped_dir("protocols") / "walker_sweep.yaml").read_text().replace("model: rod5g", "model: auto")
    with pytest.raises(ConfigError, match=r"sim\.model"):
        sim_slice(parse_protocol(text))
    with pytest.raises(CalibrationInputError, match=r"sim\.model"):
        get_rig("walker").base(_targets("walker", text))
