"""Code, tests, benchmarks and docs say what they do and check, not which work item asked for it: no text cites an
issue's or a research session's number (a reader outside the project's tracker cannot follow it, and it goes stale
as the code moves on)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("src", "tests", "benchmarks", "docs", "protocols", "sim_backend", "calibration")
SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".txt"}
# the word issue(s) or research followed by a number, in any case; not "#865" (a search's point numbers)
CITATION = re.compile(r"\bissues?\s+\d|\bresearch\d", re.IGNORECASE)


def _texts() -> list[Path]:
    files = [ROOT / "README.md"]
    for folder in FOLDERS:
        files += [p for p in sorted((ROOT / folder).rglob("*")) if p.suffix in SUFFIXES and p.is_file()]
    return files


def test_no_text_cites_a_work_items_number():
    hits = [
        f"{path.relative_to(ROOT)}:{n}: {line.strip()[:120]}"
        for path in _texts()
        for n, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1)
        if CITATION.search(line)
    ]
    assert len(_texts()) > 100  # the checkout's files, not an empty folder
    assert not hits, "\n".join(hits)
