"""One exit-code table for every command: docs/commands.md's "Exit codes" says what ``EXIT_CODES`` declares, every
command of the CLI is declared, and each command module exits only with its commands' declared codes (read from
its code: ``fail(…, code)``, ``typer.Exit(code)``, ``sys.exit(code)``, a table of codes), each special code used."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import typer

import beambench.commands as commands
from beambench.cli import app
from beambench.commands import EVERY, EXIT_CODES

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "beambench"

# which commands each module registers (a module may register two: run and view, analyze and compare)
MODULES = {
    "run": ("run", "view"),
    "analyze": ("analyze", "compare"),
    "devices": ("devices",),
    "doctor": ("doctor",),
    "calibrate": ("calibrate loadcells",),
    "calibrate_sim": ("calibrate sim",),
    "natnet": ("natnet decode",),
    "bench": ("bench models",),
    "fit": ("fit",),
    "sweep": ("sweep",),
}


def documented() -> dict[str, set[int]]:
    """docs/commands.md's exit-code table as command → codes ("every command" in a row: all of them)."""
    text = (ROOT / "docs" / "commands.md").read_text()
    section = text.split("## Exit codes", 1)[1].split("\n## ", 1)[0]
    out: dict[str, set[int]] = {name: set() for name in EXIT_CODES}
    rows = [line for line in section.splitlines() if re.match(r"\|\s*\d+\s*\|", line)]
    assert rows, "no exit-code table in docs/commands.md"
    for line in rows:
        cells = [c.strip() for c in line.strip("|").split("|")]
        code, who = int(cells[0]), cells[-1]
        names = list(EXIT_CODES) if who == "every command" else re.findall(r"`([^`]+)`", who)
        for name in names:
            assert name in out, f"docs/commands.md names an unknown command {name!r}"
            out[name].add(code)
    return out


def cli_commands(group: typer.Typer, prefix: str = "") -> set[str]:
    names = {f"{prefix}{c.name or c.callback.__name__}" for c in group.registered_commands}  # type: ignore[union-attr]
    for sub in group.registered_groups:
        names |= cli_commands(sub.typer_instance, f"{prefix}{sub.name} ")  # type: ignore[arg-type]
    return names


def codes_used(path: Path, passes_through: tuple[str, ...] = ()) -> set[int]:
    """Every exit code ``path`` can leave with, read from its syntax tree; ``passes_through``: expressions that
    hand on another's code (the entry point: a command's own, click's usage error)."""
    consts = {n: v for n, v in vars(commands).items() if n.startswith("EXIT_") and isinstance(v, int)}

    def value(node: ast.AST) -> int:
        if ast.unparse(node) in passes_through:
            return commands.EXIT_OK
        if isinstance(node, ast.Constant) and isinstance(node.value, int):
            return node.value
        if isinstance(node, ast.Name) and node.id in consts:
            return consts[node.id]
        raise AssertionError(f"{path.name}:{node.lineno}: exit code {ast.unparse(node)} is not a known constant")

    used: set[int] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call):
            name = ast.unparse(node.func)
            if name in ("fail", "_fail"):
                used.add(value(node.args[1]) if len(node.args) > 1 else commands.EXIT_USAGE)
            elif name in ("typer.Exit", "sys.exit") and node.args:
                if isinstance(node.args[0], ast.Call):  # RUN_EXIT_CODES.get(status, EXIT_FAULT)
                    used |= {value(a) for a in node.args[0].args[1:]}
                else:
                    used.add(value(node.args[0]))
        elif (
            isinstance(node, ast.Assign)
            and isinstance(node.value, ast.Dict)
            and any(isinstance(t, ast.Name) and t.id.endswith("EXIT_CODES") for t in node.targets)
        ):
            used |= {value(v) for v in node.value.values if v is not None}
    return used


def test_the_docs_table_is_the_declared_codes_of_every_command():
    assert cli_commands(app) == set(EXIT_CODES)  # every command has its row, no row without a command
    assert documented() == {name: set(codes) for name, codes in EXIT_CODES.items()}


def test_each_command_exits_only_with_its_declared_codes_and_uses_its_own():
    assert {c for names in MODULES.values() for c in names} == set(EXIT_CODES)
    passed_on = ("exc.exit_code", "code if isinstance(code, int) else 0")
    assert codes_used(SRC / "cli.py", passed_on) <= set(
        EVERY
    )  # what the entry point adds: Ctrl-C, out of memory, usage
    for module, names in MODULES.items():
        used = codes_used(SRC / "commands" / f"{module}.py")
        declared = {c for n in names for c in EXIT_CODES[n]}
        assert used <= declared, (module, used - declared)
        special = declared - set(EVERY)
        assert special <= used, (module, special - used)  # a code only one command has is really used by it


def test_calibrate_sim_help_states_the_shared_codes():
    from beambench.commands.calibrate_sim import EPILOG

    said = {int(m) for m in re.findall(r"(?:status: |; )(\d) ", EPILOG)}
    assert said == set(EXIT_CODES["calibrate sim"]), said
