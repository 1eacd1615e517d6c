"""Progress where nobody watches a terminal (a log file, a pipe, CI): plain timestamped lines while the work runs,
not one burst at the end (``beambench.common.console.LogProgress``, used by every long command)."""

from __future__ import annotations

import io
import itertools
import os
import re
import subprocess
import sys
import threading
import time

from rich.console import Console

from beambench.common.console import PROGRESS_ENV, LogProgress
from conftest import wait_until

STAMP = re.compile(r"^(\d\d):(\d\d):(\d\d) (.*)$")


def test_plain_lines_arrive_while_the_task_runs_and_a_last_one_at_the_end(monkeypatch):
    monkeypatch.setenv(PROGRESS_ENV, "0.05")
    out = io.StringIO()
    console = Console(file=out, force_terminal=False, width=200)
    with LogProgress(console=console) as progress:
        assert progress.plain
        task = progress.add_task("[bold]fitting", total=10, err="best 1 mm")
        progress.update(task, completed=3)
        wait_until(lambda: out.getvalue().count("\n") >= 2, 60)  # lines while the task is still running
        running = out.getvalue()
        progress.update(task, completed=10)
    lines = out.getvalue().splitlines()
    assert all(STAMP.match(line) for line in lines), lines
    assert "fitting: 3/10 (30 %), best 1 mm, 0:00:00 elapsed" in running, running
    assert lines[-1].endswith("fitting: 10/10 (100 %), best 1 mm, 0:00:00 elapsed"), lines[-1]
    assert "[bold]" not in running and "" not in lines


def test_a_transient_display_ends_without_a_line_or_a_blank_one(monkeypatch):
    monkeypatch.setenv(PROGRESS_ENV, "30")
    out = io.StringIO()
    with LogProgress(console=Console(file=out, force_terminal=False), transient=True) as progress:
        progress.add_task("analysing", total=2)
    assert out.getvalue() == ""


def test_a_terminal_gets_rich_live_bar_not_plain_lines():
    out = io.StringIO()
    progress = LogProgress(console=Console(file=out, force_terminal=True))
    assert not progress.plain


def test_a_run_on_a_pipe_prints_timestamped_progress_during_the_run(tmp_path):
    """``beambench run`` with stderr on a pipe: progress lines at least every interval (0.05 s here; 10 s by
    default), each with its time, arriving while the run goes on rather than all at its end."""
    proto = tmp_path / "p.yaml"
    freqs = ", ".join(str(f) for f in range(5, 45))
    proto.write_text(f"name: p\nrig: contact\nsweep: {{frequencies: [{freqs}]}}\nsettle_s: 0.5\nrecord_s: 2.5\n")
    env = dict(os.environ, **{PROGRESS_ENV: "0.05"})
    cmd = [sys.executable, "-m", "beambench", "run", str(proto), "--out", str(tmp_path), "--rerun", "off"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    arrivals: list[tuple[float, str]] = []
    stdout: list[str] = []
    reader = threading.Thread(target=lambda: stdout.append(proc.stdout.read() if proc.stdout else ""))
    reader.start()
    assert proc.stderr is not None
    for line in proc.stderr:
        arrivals.append((time.monotonic(), line.rstrip("\n")))
    assert proc.wait(timeout=300) == 0, [line for _, line in arrivals]
    reader.join()
    proc.stdout.close()  # type: ignore[union-attr]
    proc.stderr.close()
    progress = [(t, line) for t, line in arrivals if STAMP.match(line) and " Hz: " in line]
    assert len(progress) >= 4, arrivals
    stamps = [int(h) * 3600 + int(m) * 60 + int(s) for h, m, s, _ in (STAMP.match(x).groups() for _, x in progress)]
    assert max(b - a for a, b in itertools.pairwise(stamps)) <= 10, stamps
    # lines come while the run goes on: the first at least one interval before the last (not one burst at the end)
    assert progress[-1][0] - progress[0][0] >= 0.1, progress
    assert stdout[0].strip().endswith(".h5")


def test_a_budgeted_search_says_its_time_left_each_time_the_line_is_shown(monkeypatch):
    """``calibrate sim``'s line: the same generation's line shown twice still moves, with the time left of its
    budget (a ``TimeLeft`` field reads the clock when shown), then says the budget is spent."""
    from beambench.common.console import TimeLeft, plain_line

    now = [100.0]
    left = TimeLeft(150.0, clock=lambda: now[0])
    progress = LogProgress(console=Console(file=io.StringIO(), force_terminal=False, width=200))
    task = progress.add_task("coarse gen 1: best coarse J 1.541 (8 run, 0 reused)", total=None, left=left)
    first = plain_line(progress.tasks[task])
    now[0] += 70.0
    second = plain_line(progress.tasks[task])
    now[0] += 90.0
    third = plain_line(progress.tasks[task])
    assert "2:30 left of the 150 s budget" in first and "1:20 left of the 150 s budget" in second, (first, second)
    assert "150 s budget spent: finishing" in third
