"""``sweep: {start, stop, step}`` has an inclusive stop (README): a step that does not land on it is refused with
one line naming the field and the steps that would fit (1 to 10 by 4 must not silently give 1, 5, 9)."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from beambench.acquisition.protocol.schema import parse_protocol
from beambench.cli import app
from beambench.common.yaml_config import ConfigError

BASE = "name: t\nsettle_s: 0.2\nrecord_s: 0.3\nsweep: {sweep}\n"


def test_a_step_that_jumps_over_stop_is_one_line_in_a_dry_run(tmp_path):
    proto = tmp_path / "p.yaml"
    proto.write_text(BASE.format(sweep="{start: 1, stop: 10, step: 4}"))
    res = CliRunner().invoke(app, ["run", str(proto), "--dry-run"])
    errors = [ln for ln in res.output.splitlines() if ln.startswith("beambench: error:")]
    assert res.exit_code == 2 and len(errors) == 1, res.output
    assert "sweep" in errors[0] and "step = 4" in errors[0] and "stop = 10" in errors[0], errors
    assert "step 3 or 4.5" in errors[0] and "stop 9" in errors[0], errors


@pytest.mark.parametrize(
    "sweep, values",
    [
        ("{start: 1, stop: 10, step: 3}", [1, 4, 7, 10]),
        ("{start: 2, stop: 40, step: 0.19}", None),  # 201 steps: floating point lands within tolerance
        ("{start: 0.1, stop: 0.7, step: 0.1}", [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]),
        ("{start: 5, stop: 5, step: 1}", [5]),
    ],
)
def test_steps_that_land_on_stop_are_accepted(sweep, values):
    p = parse_protocol(BASE.format(sweep=sweep), "p.yaml")
    got = p.sweep.values()
    assert got[-1] == pytest.approx(p.sweep.stop)
    if values is not None:
        assert got == pytest.approx(values)


def test_the_error_is_a_config_error():
    with pytest.raises(ConfigError, match="does not land on stop"):
        parse_protocol(BASE.format(sweep="{start: 1, stop: 2, step: 0.3}"), "p.yaml")
