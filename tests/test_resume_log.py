"""The calibrator's resume log: a last line cut by a kill (no newline) is skipped with a warning and
cut off, so the next evaluation is not appended onto it and lost; ``calibrate sim`` stopped by Ctrl-C says where
its evaluations are and how to resume."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from beambench.commands import EXIT_STOPPED
from beambench.common.jsonl import append_record, read_records
from conftest import wait_until

ROOT = Path(__file__).resolve().parents[1]


def _cut_log(path: Path) -> None:
    """Two whole records, then a third cut mid-way by a kill."""
    whole = [json.dumps({"key": "a", "j": 1.0}), json.dumps({"key": "b", "j": 2.0})]
    path.write_text("\n".join(whole) + "\n" + json.dumps({"key": "c", "j": 3.0})[:12])


def test_a_cut_last_line_is_skipped_with_a_warning_and_cut_off(tmp_path):
    log = tmp_path / "x.evals.jsonl"
    _cut_log(log)
    said: list[str] = []
    records = read_records(log, "evaluation log", warn=said.append)
    assert [r["key"] for r in records] == ["a", "b"]
    assert len(said) == 1 and "last line was cut" in said[0] and str(log) in said[0]
    assert log.read_bytes().endswith(b"}\n")  # repaired: the next append starts a line of its own
    append_record(log, {"key": "d"})
    assert [r["key"] for r in read_records(log, warn=said.append)] == ["a", "b", "d"] and len(said) == 1


def test_append_starts_a_new_line_after_a_cut_one_even_unread(tmp_path):
    log = tmp_path / "y.jsonl"
    log.write_text('{"key": "a"}\n{"key": "b", "j"')
    append_record(log, {"key": "c"})
    said: list[str] = []
    assert [r["key"] for r in read_records(log, warn=said.append, repair=False)] == ["a", "c"]
    assert len(said) == 1 and "1 line that are not JSON" in said[0]


def test_a_last_record_without_its_newline_is_kept(tmp_path):
    log = tmp_path / "z.jsonl"
    log.write_text('{"key": "a"}\n{"key": "b"}')
    assert [r["key"] for r in read_records(log, warn=pytest.fail)] == ["a", "b"]
    assert log.read_text().endswith("}\n")


def test_the_calibrators_log_keeps_the_evaluation_after_a_cut_line(tmp_path):
    """The evaluation finished after a resume used to be appended onto the cut line: both lost on the next resume."""
    from beambench.studies.twin_calibration.evaluate import EvalLog

    path = tmp_path / "r.evals.jsonl"
    _cut_log(path)
    log = EvalLog(path)
    assert set(log.cache) == {"a", "b"}
    log.add({"key": "c", "j": 3.0})
    assert set(EvalLog(path).cache) == {"a", "b", "c"}


@pytest.mark.slow
def test_calibrate_sim_stopped_by_ctrl_c_says_how_to_resume(tmp_path):
    src = str(ROOT / "src")
    env = dict(os.environ, PYTHONPATH=os.environ.get("PYTHONPATH") or src, PYTHONUNBUFFERED="1", PYTHONFAULTHANDLER="1")
    targets = ROOT / "calibration" / "paper_contact_targets.yaml"
    cmd = [sys.executable, "-m", "beambench.cli", "calibrate", "sim", "--targets", str(targets), "--quick"]
    cmd += ["--out", str(tmp_path), "--workers", "1", "--name", "c"]
    err_path = tmp_path / "err.txt"
    with err_path.open("wb") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, env=env, start_new_session=True)
        try:
            log = tmp_path / "c.evals.jsonl"  # written after the first evaluation: imports done, the search running

            def evaluated() -> bool:
                assert proc.poll() is None, err_path.read_text()[-2000:]
                return log.exists() and log.stat().st_size > 0

            wait_until(evaluated, 180, "the first evaluation", 0.05)
            assert proc.poll() is None, err_path.read_text()[-2000:]
            os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in the terminal sends: the whole process group
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=60)
        finally:
            if proc.poll() is None:  # hung: every thread's stack into the log (faulthandler on SIGABRT), then fail
                os.kill(proc.pid, signal.SIGABRT)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(timeout=10)
                if proc.poll() is None:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
    text = err_path.read_text(errors="replace")
    assert proc.returncode == EXIT_STOPPED == 3, text[-2000:]  # stopped, as every command on Ctrl-C
    assert "Traceback" not in text, text[-3000:]
    said = [line for line in text.replace("\r", "\n").splitlines() if line.startswith("beambench:")]
    assert len(said) == 1, said
    assert "to resume, run beambench calibrate sim" in said[0] and str(tmp_path / "c.evals.jsonl") in said[0], said
