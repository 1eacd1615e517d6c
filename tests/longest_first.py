"""Longest test modules first, for ``make test``'s ``--dist loadfile --no-loadscope-reorder``.

With ``loadfile`` each xdist worker takes whole modules (a module's shared fixtures are made once, in one worker)
from one queue, in collection order. This plugin orders that queue by each module's wall time in the previous
run, longest first (longest-processing-time scheduling), so a run does not end with three workers idle while a long
module that started last finishes. The times live in pytest's cache (``.pytest_cache``, git-ignored), merged
after every run of any selection; modules the cache does not know yet (a fresh clone, a new module) go first,
most tests first (xdist's own order). The order of the tests inside a module is kept.
"""

from __future__ import annotations

from collections import Counter, defaultdict

import pytest

CACHE_KEY = "beambench/module_seconds"
_spent: defaultdict[str, float] = defaultdict(float)


def _module(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def module_order(modules: list[str], tests: Counter[str], seconds: dict[str, float]) -> list[str]:
    """``modules`` (each once) in the order to run them: unknown to ``seconds`` first by test count, then by
    seconds, both largest first; ties keep the given order."""
    return sorted(modules, key=lambda m: (0, -tests[m]) if m not in seconds else (1, -seconds[m]))


@pytest.hookimpl(trylast=True)  # after conftest's soak selection
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    cache = getattr(config, "cache", None)
    if cache is None:
        return
    seconds = cache.get(CACHE_KEY, {})
    by_module: dict[str, list[pytest.Item]] = {}
    for item in items:
        by_module.setdefault(_module(item.nodeid), []).append(item)
    tests = Counter({m: len(group) for m, group in by_module.items()})
    items[:] = [item for m in module_order(list(by_module), tests, seconds) for item in by_module[m]]


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    _spent[_module(report.nodeid)] += report.duration  # setup, call and teardown


def pytest_sessionfinish(session: pytest.Session) -> None:
    config = session.config
    cache = getattr(config, "cache", None)
    if cache is None or hasattr(config, "workerinput") or not _spent:  # the controller (or a plain run) writes
        return
    seconds = dict(cache.get(CACHE_KEY, {}))
    seconds.update({m: round(s, 2) for m, s in _spent.items()})
    cache.set(CACHE_KEY, seconds)
