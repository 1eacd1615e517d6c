"""``run`` and a stop signal that came before its run started — while the command line imported, or while the command
read and checked its protocol: a dry run, a bad protocol or a bad flag then ends with one line and the interrupted
exit code, no traceback, never as if nothing had come (exit 0) or with only the bad input's line."""

from __future__ import annotations

import pytest

from beambench.commands import EXIT_STOPPED
from import_stops import stopped_at_import

# pydantic: imported while the command line imports its commands; numpy: by ``run`` as it checks the protocol and
# estimates its run time; rich: as the dry run prints its plan
PACKAGES = ["pydantic", "numpy", "rich"]


def _said(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if ln.startswith("beambench:")]


@pytest.mark.parametrize("package", PACKAGES)
def test_a_stop_before_a_dry_run_ends_it_interrupted(tmp_path, package):
    code, err = stopped_at_import(tmp_path, package, "Python", ["run", "contact_sweep", "--dry-run"])
    assert code == EXIT_STOPPED, err[-2000:]
    assert _said(err) == [
        "beambench: dry run interrupted: interrupted by user (SIGINT) (nothing moved; no session written)"
    ], err[-2000:]
    assert "Traceback" not in err, err[-2000:]


def test_a_stop_while_a_bad_protocol_is_checked_ends_it_interrupted(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("sweep: {start_hz: 1, stop_hz: 5, step_hz: 1}\nsim: {no_such_field: 1}\n")
    code, err = stopped_at_import(tmp_path, "beambench.session", "Python", ["run", str(bad)])
    assert code == EXIT_STOPPED, err[-2000:]
    assert _said(err) == [
        "beambench: run interrupted: interrupted by user (SIGINT) (nothing moved; no session written)"
    ], err[-2000:]
    assert "Traceback" not in err, err[-2000:]


def test_a_stop_while_the_command_line_imports_ends_a_run_with_bad_flags_interrupted(tmp_path):
    code, err = stopped_at_import(tmp_path, "pydantic", "Python", ["run", "contact_sweep", "--no-such-flag"])
    assert code == EXIT_STOPPED, err[-2000:]
    assert _said(err) == ["beambench: aborted"], err[-2000:]
    assert "Traceback" not in err, err[-2000:]
