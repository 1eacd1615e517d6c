"""The installed entry point: usage errors are one line on stderr with exit code 2, like config errors;
help is not an error."""

from __future__ import annotations

import subprocess
import sys

import pytest


def _beambench(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "beambench.cli", *args], capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize(
    "args, words",
    [
        (["run"], "Missing argument 'PROTOCOL'"),
        (["frobnicate"], "No such command 'frobnicate'"),
        (["bench", "models", "--quick", "--out"], "Option '--out' requires an argument"),
        (["run", "protocols/contact_sweep.yaml", "--rerun", "bogus"], "'bogus' is not one of 'spawn'"),
    ],
)
def test_usage_errors_are_one_line_and_exit_2(args, words):
    res = _beambench(*args)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("beambench: error: ") and words in lines[0], res.stderr
    assert "Traceback" not in res.stderr and "╭" not in res.stderr


def test_bare_command_and_help_exit_0():
    for args in ([], ["run", "--help"]):
        res = _beambench(*args)
        assert res.returncode == 0 and "Usage: beambench" in res.stdout
