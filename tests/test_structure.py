"""The code's shape, checked from its syntax trees: each layer gets its own slice of a protocol, no module
reaches for another's private names."""

from __future__ import annotations

import ast
from pathlib import Path

import beambench

PACKAGE = Path(beambench.__file__).parent
# below session/: these receive slices (SimSlice, markers, settings), never the whole protocol; acquisition/ is the
# protocol's own home (its schema and step plan)
SLICED = ("backends", "sim", "emulators", "sinks", "devices", "analysis")


def _modules(*packages: str) -> list[Path]:
    roots = [PACKAGE / p for p in packages] if packages else [PACKAGE]
    return sorted(p for root in roots for p in root.rglob("*.py"))


def _name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _imports_protocol_model(tree: ast.Module) -> bool:
    return any(
        isinstance(node, ast.ImportFrom)
        and node.module == "beambench.acquisition.config"
        and any(a.name == "Protocol" for a in node.names)
        for node in ast.walk(tree)
    )


def test_no_layer_below_session_takes_the_whole_protocol() -> None:
    found = []
    for path in _modules(*SLICED):
        tree = ast.parse(path.read_text())
        if not _imports_protocol_model(tree):
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                args = [*node.args.posonlyargs, *node.args.args, *node.args.kwonlyargs]
                found += [
                    f"{_name(path)}.{node.name}({a.arg})"
                    for a in args
                    if a.annotation is not None and "Protocol" in ast.unparse(a.annotation).split(" | ")
                ]
    assert found == []


def test_no_module_imports_another_packages_private_names() -> None:
    """A leading underscore is private to its package (natnet's frame parsers share wire.py's readers)."""
    found = []
    for path in _modules():
        home = _name(path).rsplit(".", 1)[0] if path.name != "__init__.py" else _name(path)
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("beambench"):
                there = (node.module or "").rsplit(".", 1)[0]
                private = [a.name for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
                found += [f"{_name(path)}: {node.module}.{n}" for n in private if there != home]
    assert found == []
