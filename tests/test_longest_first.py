"""The suite's module order (tests/longest_first.py): the longest modules of the last run first, unknown ones
before them by test count, each module's tests together and in their own order."""

from __future__ import annotations

from collections import Counter

from longest_first import CACHE_KEY, module_order

pytest_plugins = ["pytester"]


def test_known_modules_run_longest_first_after_the_unknown_ones_by_test_count():
    tests = Counter({"a.py": 3, "b.py": 9, "c.py": 1, "d.py": 5, "e.py": 2})
    seconds = {"a.py": 4.0, "c.py": 30.0, "e.py": 4.0}
    assert module_order(list(tests), tests, seconds) == ["b.py", "d.py", "c.py", "a.py", "e.py"]


def test_a_run_records_its_modules_times_and_the_next_run_orders_by_them(pytester):
    pytester.makeconftest('pytest_plugins = ["longest_first"]')
    pytester.makepyfile(
        test_quick="def test_q1(): pass\ndef test_q2(): pass\ndef test_q3(): pass",
        # a module that takes 0.3 s (its length is the test's input; busy, so no sleep to flag)
        test_slow="import time\ndef test_s1():\n    t = time.monotonic()\n    while time.monotonic() - t < 0.3:\n        pass\n"
        "def test_s2(): pass",
    )
    first = pytester.runpytest("--collect-only", "-q")
    assert [ln.split("::")[0] for ln in first.outlines if "::" in ln][:1] == ["test_quick.py"]  # most tests first
    pytester.runpytest().assert_outcomes(passed=5)
    seconds = pytester.parseconfigure().cache.get(CACHE_KEY, {})
    assert seconds["test_slow.py"] > 0.25 > seconds["test_quick.py"]
    second = pytester.runpytest("--collect-only", "-q")
    order = [ln for ln in second.outlines if "::" in ln]
    assert order == [
        "test_slow.py::test_s1",
        "test_slow.py::test_s2",
        "test_quick.py::test_q1",
        "test_quick.py::test_q2",
        "test_quick.py::test_q3",
    ]
