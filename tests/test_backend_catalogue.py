"""Backends are a catalogue (``acquisition/protocol/backends.py``) with a rig builder registered for each; the
rest of the code asks a backend's flags, never compares its name."""

from __future__ import annotations

import ast
from pathlib import Path

import beambench
from beambench.acquisition.protocol.backends import BACKEND_INFO, backends_with
from beambench.acquisition.protocol.schema import BACKENDS
from beambench.backends.build import BUILDERS

PACKAGE = Path(beambench.__file__).parent


def test_every_backend_of_the_protocol_model_is_catalogued_and_has_a_rig_builder():
    assert tuple(BACKEND_INFO) == BACKENDS
    assert set(BUILDERS) == set(BACKENDS)
    assert backends_with("devices") == ["emulated", "hardware"] and backends_with("simulated_clock") == ["sim"]


def test_no_module_compares_a_backend_name():
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "backends.py" and path.parent.name == "protocol":
            continue  # the catalogue itself
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare) and any(isinstance(op, ast.Eq | ast.NotEq) for op in node.ops):
                sides = [node.left, *node.comparators]
                named = any(isinstance(s, ast.Constant) and s.value in BACKENDS for s in sides)
                about = any("backend" in ast.unparse(s) for s in sides if not isinstance(s, ast.Constant))
                if named and about:
                    found.append(f"{path.relative_to(PACKAGE)}:{node.lineno} {ast.unparse(node)}")
    assert found == []
