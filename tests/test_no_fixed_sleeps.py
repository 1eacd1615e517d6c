"""No fixed sleep in the tests: a test waits for a condition (conftest's ``wait_until`` / ``holds_for``), and a
delay that is the test's input says so (``pause`` / ``random_moment``); those helpers in conftest.py are the only
code a sleep is called in. The same holds in the code strings a test runs in a child process (a stand-in peer, a
script): there a sleep sits in a helper of one of those names that the string defines (a child that cannot import
conftest)."""

from __future__ import annotations

import ast
import textwrap
from pathlib import Path

TESTS = Path(__file__).resolve().parent
HELPERS = {"wait_until", "holds_for", "pause"}  # the only functions a sleep may be called in


def _sleep_names(tree: ast.AST) -> tuple[set[str], set[str]]:
    """The names ``time`` is imported as, and the names ``time.sleep`` itself is imported as."""
    modules, functions = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules |= {a.asname or a.name for a in node.names if a.name == "time"}
        elif isinstance(node, ast.ImportFrom) and node.module == "time":
            functions |= {a.asname or a.name for a in node.names if a.name == "sleep"}
    return modules, functions


def _is_sleep(f: ast.expr, modules: set[str], functions: set[str]) -> bool:
    """``f`` names ``time.sleep``: ``time.sleep`` (or an alias of ``time``), or ``sleep`` imported from ``time``."""
    if isinstance(f, ast.Attribute):
        return f.attr == "sleep" and isinstance(f.value, ast.Name) and f.value.id in modules
    return isinstance(f, ast.Name) and f.id in functions


def _bare_sleeps(tree: ast.AST, helpers: set[str]) -> list[int]:
    """Lines of ``time.sleep(…)`` calls outside a function named in ``helpers``."""
    modules, functions = _sleep_names(tree)
    found: list[int] = []

    def visit(node: ast.AST, allowed: bool) -> None:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            allowed = node.name in helpers
        if isinstance(node, ast.Call) and not allowed and _is_sleep(node.func, modules, functions):
            found.append(node.lineno)
        for child in ast.iter_child_nodes(node):
            visit(child, allowed)

    visit(tree, False)
    return found


def _code_strings(tree: ast.AST) -> list[tuple[int, str]]:
    """String literals that mention a sleep (f-strings with their fields as a placeholder name), dedented."""
    out = []
    parts_of_fstrings = {id(v) for node in ast.walk(tree) if isinstance(node, ast.JoinedStr) for v in node.values}
    for node in ast.walk(tree):
        if id(node) in parts_of_fstrings:
            continue
        if isinstance(node, ast.JoinedStr):
            parts = [v.value if isinstance(v, ast.Constant) else "_field" for v in node.values]
            text = "".join(str(p) for p in parts)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            text = node.value
        else:
            continue
        if "sleep(" in text:
            out.append((node.lineno, textwrap.dedent(text)))
    return out


def fixed_sleeps(path: Path) -> list[str]:
    """``file:line`` of each fixed sleep in one test module, in its own code or in a code string it runs."""
    tree = ast.parse(path.read_text(), str(path))
    where = [f"{path.name}:{line}" for line in _bare_sleeps(tree, HELPERS if path.name == "conftest.py" else set())]
    for line, code in _code_strings(tree):
        try:
            inner = ast.parse(code)
        except SyntaxError:
            where.append(f"{path.name}:{line} (a string mentioning sleep( that is not code: cannot be checked)")
            continue
        where += [f"{path.name}:{line} (code string, its line {n})" for n in _bare_sleeps(inner, HELPERS)]
    return where


def test_no_fixed_sleep_outside_a_polling_or_input_helper() -> None:
    files = sorted(TESTS.glob("*.py"))
    assert len(files) > 50 and TESTS / "conftest.py" in files
    files.remove(Path(__file__).resolve())  # this file's probe spells sleeps on purpose
    found = [w for path in files for w in fixed_sleeps(path)]
    assert not found, "wait with wait_until/holds_for, or name a delay that is an input with pause/random_moment: " + (
        ", ".join(found)
    )


def test_the_check_finds_each_spelling_of_a_sleep(tmp_path: Path) -> None:
    """The checker itself: every way of calling sleep is found, in code and in code strings; the helpers pass in
    conftest.py and in code strings, not in a test module."""
    code = (
        "import time\nimport time as _t\nfrom time import sleep as nap\n"
        "def wait_until():\n    time.sleep(0.01)\n"
        "def f():\n    time.sleep(1)\n    _t.sleep(1)\n    nap(1)\n"
        "CODE = 'import time\\nfor _ in range(3):\\n    time.sleep(0.1)\\n'\n"
        "OK = 'import time\\ndef pause(s, why):\\n    time.sleep(s)\\n'\n"
        "PROSE = 'call sleep( here'\n"
    )
    (tmp_path / "test_probe.py").write_text(code)
    (tmp_path / "conftest.py").write_text(code)
    found = fixed_sleeps(tmp_path / "test_probe.py")
    lines = [w.split(" ")[0].split(":")[1] for w in found]
    assert lines == ["5", "7", "8", "9", "10", "12"], found
    assert "its line 3" in found[4] and "not code" in found[5]
    in_conftest = fixed_sleeps(tmp_path / "conftest.py")  # its wait_until may sleep: the rest is found as before
    assert [w.split(" ")[0] for w in in_conftest][:4] == [
        "conftest.py:7",
        "conftest.py:8",
        "conftest.py:9",
        "conftest.py:10",
    ]
