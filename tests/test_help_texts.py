"""The help says what the commands do: the calibrator's unknowns come from its registry; the emulated load-cell
calibration names the file it writes."""

from __future__ import annotations

import re

from typer.testing import CliRunner

from beambench.cli import app


def _help(*command: str) -> str:
    res = CliRunner().invoke(app, [*command, "--help"], env={"COLUMNS": "400", "TERMINAL_WIDTH": "400"})
    assert res.exit_code == 0, res.output
    return re.sub(r"[│╭╮╰╯─]", " ", res.stdout)


def _option_text(text: str, option: str) -> str:
    """The help of one option: from its name to the next option's."""
    after = re.split(rf"\n\s*{option}\s", text, maxsplit=1)[1]
    return " ".join(re.split(r"\n\s+--[a-z]", after, maxsplit=1)[0].split())


def test_calibrate_sim_help_lists_every_rigs_unknowns_from_the_registry():
    from beambench.studies.twin_calibration import RIGS

    free = _option_text(_help("calibrate", "sim"), "--free")
    assert len(RIGS) >= 2
    for rig in RIGS.values():
        default = ", ".join(rig.default_free)
        assert f"{rig.name} rig: {default} by default" in free, free
        for unknown in rig.unknowns:
            assert unknown.name in free, (unknown.name, free)
    assert "stiffness and damping" not in free


def test_calibrate_loadcells_emulate_help_names_the_file_it_writes():
    emulate = _option_text(_help("calibrate", "loadcells"), "--emulate")
    assert "loadcells-emulated.yaml" in emulate and "not loadcells.yaml" in emulate, emulate
