"""``analyze`` checks every place it writes before it writes anything: a read-only report folder or
session is one line and exit 2, and the session is left as it was (``/processing`` was written first, then a
PermissionError traceback, exit 1). Analysing a session again does not grow it (~9 kB per run before).

Read-only here is a read-only mount (root ignores permission bits) where the test can mount one, else a folder
without write permission (for other users)."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from beambench.analysis.synthetic import SynthSession, SynthStep, write_synthetic_session
from beambench.cli import app


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("ro")
    return write_synthetic_session(
        d / "s.h5", SynthSession([SynthStep(12.0, 1), SynthStep(26.0, 2)], record_s=1.5, settle_s=0.3, seed=4)
    )


@pytest.fixture
def read_only(tmp_path: Path) -> Iterator[Path]:
    """An empty folder nobody can write into."""
    folder = tmp_path / "ro"
    folder.mkdir()
    if os.geteuid() != 0:
        folder.chmod(0o555)
        yield folder
        folder.chmod(0o755)
        return
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(folder)], capture_output=True)
    if res.returncode != 0:
        pytest.skip(f"root, and cannot mount a read-only tmpfs: {res.stderr.decode().strip()[:100]}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], capture_output=True)


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _one_line_exit_2(res, *words: str) -> None:
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise AssertionError(f"traceback instead of one line: {res.exception!r}") from res.exception
    errors = [ln for ln in res.output.splitlines() if ln.startswith("beambench: error:")]
    assert res.exit_code == 2, res.output
    assert len(errors) == 1 and all(w in errors[0] for w in words), res.output


def test_a_read_only_report_folder_is_one_line_and_the_session_is_untouched(session, tmp_path, read_only):
    copy = tmp_path / "s.h5"
    shutil.copy(session, copy)
    before = _digest(copy)
    res = CliRunner().invoke(app, ["analyze", str(copy), "--out", str(read_only / "report"), "-q"])
    _one_line_exit_2(res, str(read_only), "report folder")
    assert _digest(copy) == before, "the session was written before the outputs were checked"


def test_a_session_in_a_read_only_folder_is_one_line(session, tmp_path, read_only):
    if os.geteuid() == 0:  # the mount is empty and read-only: bind the session in with a second mount
        res = subprocess.run(["mount", "-o", "remount,rw", str(read_only)], capture_output=True)
        assert res.returncode == 0
        shutil.copy(session, read_only / "s.h5")
        assert subprocess.run(["mount", "-o", "remount,ro", str(read_only)], capture_output=True).returncode == 0
    else:
        read_only.chmod(0o755)
        shutil.copy(session, read_only / "s.h5")
        (read_only / "s.h5").chmod(0o444)
        read_only.chmod(0o555)
    path = read_only / "s.h5"
    res = CliRunner().invoke(app, ["analyze", str(path), "-q"])
    _one_line_exit_2(res, str(read_only))


def test_analysing_again_does_not_grow_the_session(session, tmp_path):
    """What analyze stores (write_results), three times: the second and third leave the size as it was."""
    from beambench.analysis.session_analysis import analyze_session, write_results
    from beambench.sinks.session_file.reader import read_processing, read_session

    copy = tmp_path / "s.h5"
    shutil.copy(session, copy)
    analysis = analyze_session(read_session(copy))
    sizes = []
    for _ in range(3):
        write_results(analysis)
        sizes.append(copy.stat().st_size)
    assert sizes[1:] == [sizes[0]] * 2, sizes
    assert len(read_processing(copy, "steps")) == 2
