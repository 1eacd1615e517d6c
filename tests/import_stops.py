"""A stop signal at an exact moment of a command's start, the same every time: SIGINT at the first import of a
package, for the tests of how each command takes a stop that came while it imported."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# A stop at an exact moment, the same every time: the command line runs under this driver, which sends the process
# SIGINT when the first module of a package is about to be imported (after beambench's first line) — from code run
# through CPython's PyRun_String, as an extension module's init runs Python (MuJoCo's pybind11 callbacks module does,
# on its import during the command's imports), or from plain Python code.
DRIVER = """
import ctypes, os, runpy, signal, sys

PACKAGE, VIA = sys.argv[1], sys.argv[2]
run_string = ctypes.pythonapi.PyRun_String
run_string.restype = ctypes.py_object
run_string.argtypes = [ctypes.c_char_p, ctypes.c_int, ctypes.py_object, ctypes.py_object]
STOP = "import os, signal\\nos.kill(os.getpid(), signal.SIGINT)\\nfor _ in range(10000): pass\\n"


class StopAtImport:
    fired = False

    def find_spec(self, name, path=None, target=None):
        if not self.fired and (name == PACKAGE or name.startswith(PACKAGE + ".")):
            self.fired = True
            sys.stderr.write("driver: SIGINT at the import of " + name + "\\n")
            if VIA == "PyRun_String":
                run_string(STOP.encode(), 257, {}, {})  # 257: Py_file_input
            else:
                exec(STOP)
        return None


sys.meta_path.insert(0, StopAtImport())
sys.argv = ["beambench", *sys.argv[3:]]
runpy.run_module("beambench.cli", run_name="__main__", alter_sys=True)
"""


def _sigint_as_in_a_terminal() -> None:
    """SIGINT at its default, as for a command typed in a terminal, whatever started the tests (a script's background
    job ignores it; for a command that does not take stop signals itself an ignored Ctrl-C stays ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def stopped_at_import(tmp_path: Path, package: str, via: str, args: list[str]) -> tuple[int, str]:
    (tmp_path / "stop_at_import.py").write_text(DRIVER)
    path = os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH") or str(ROOT / "src")])
    env = dict(os.environ, PYTHONPATH=path, PYTHONUNBUFFERED="1")
    proc = subprocess.run(  # as ``python -m``: the tests' (and a user's) way; CPython ends it by its own rules
        [sys.executable, "-m", "stop_at_import", package, via, *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
        text=True,
        timeout=120,
        preexec_fn=_sigint_as_in_a_terminal,
    )
    assert f"driver: SIGINT at the import of {package}" in proc.stderr, proc.stderr[-2000:]
    return proc.returncode, proc.stderr
