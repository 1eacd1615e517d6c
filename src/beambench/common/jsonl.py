"""Append-only JSON-lines logs that survive a kill (the calibrator's ``*.evals.jsonl`` resume log).

A process killed mid-write leaves its last line cut, without a newline. Read naively, the next record appended
lands on that broken line and both are lost (the resume then redoes an evaluation it had). Here a cut or
unreadable line is skipped with a one-line warning, a cut last line is cut off the file (so the next append
starts a line of its own), and :func:`append_record` makes sure the file ends with a newline before it writes.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from beambench.common.inputs import check_input_file

__all__ = ["MAX_LOG_BYTES", "append_record", "read_records"]

MAX_LOG_BYTES = 2 << 30  # 2 GiB: a million evaluations of a couple of kB


def _stderr(message: str) -> None:
    with contextlib.suppress(OSError):  # a closed terminal: the warning is not worth a traceback
        print(f"beambench: warning: {message}", file=sys.stderr, flush=True)


def read_records(
    path: str | Path, what: str = "log", warn: Callable[[str], None] = _stderr, repair: bool = True
) -> list[Any]:
    """Every JSON value of the log at ``path``, one per line, in order; lines that are not JSON are skipped
    (one warning for them all). With ``repair``, a cut last line (no newline) is also removed from the file."""
    p = Path(path)
    check_input_file(p, what, MAX_LOG_BYTES)
    raw = p.read_bytes()
    lines = raw.split(b"\n")
    tail = lines.pop()  # b"" when the file ends with a newline; else the cut last line
    records: list[Any] = []
    bad = 0
    for line in lines:
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except (json.JSONDecodeError, UnicodeDecodeError):
            bad += 1
    if tail.strip():
        try:  # a complete record that only lacks its newline is kept (and the newline added)
            records.append(json.loads(tail))
            if repair:
                with p.open("ab") as fh:
                    fh.write(b"\n")
        except (json.JSONDecodeError, UnicodeDecodeError):
            if repair:
                os.truncate(p, len(raw) - len(tail))
            warn(f"{p}: its last line was cut ({len(tail)} bytes, a killed run?): skipped, and removed from the file")
    if bad:
        warn(f"{p}: {bad} line{'s' if bad != 1 else ''} that are not JSON skipped")
    return records


def append_record(path: str | Path, record: Any, default: Callable[[Any], Any] | None = None) -> None:
    """Append ``record`` as one JSON line (flushed on close), on a line of its own even if the file's last line
    was cut."""
    line = (json.dumps(record, default=default) + "\n").encode("utf-8")
    with Path(path).open("a+b") as fh:
        if fh.tell() > 0:
            fh.seek(-1, os.SEEK_END)
            if fh.read(1) != b"\n":
                line = b"\n" + line
        fh.write(line)
