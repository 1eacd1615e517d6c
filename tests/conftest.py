"""Shared test helpers.

- :func:`shared_path` / :func:`require_shared`: the shared fixtures (independent NatNet packets and captures, the
  ODrive DBC) live outside the repository, in ``$BEAMBENCH_SHARED`` if set, else ``../shared`` beside the checkout.
  Every test that reads them goes through here and skips with the reason when they are absent, or fails when the
  environment variable ``CI`` is set (:func:`skip_unless_ci`: CI must run every test).
- Every test runs with ``$BEAMBENCH_USER_DIR`` pointing at a temporary folder, so nothing a test runs (calibrate,
  fit, …) writes into the real per-user folder.
- :func:`wait_until` / :func:`holds_for`: the one way a test waits on real time (a thread, a socket, a child
  process): poll a condition until it holds, or check that it keeps holding for a while; no fixed sleeps.
- :func:`pause` / :func:`random_moment`: where a delay *is* the test's input (a stall of a given length, a worker's
  compute time, a peer's pacing, the random moment a signal or fault is raced at), it is spelled so, saying what it
  stands for; tests/test_no_fixed_sleeps.py fails on any other ``time.sleep`` in tests/ (in code strings a child
  runs too).
- The soak tier (``@pytest.mark.soak``): more repetitions of a race check, at other random moments, than the
  default run's one or few, and the one test that runs a whole 2-min calibration search. Deselected unless
  ``--soak`` is given (``make soak``; CI runs it after ``make test``).
  Every Hypothesis test belongs to it too: the default run makes a fifth of its examples (at least 50,
  :func:`fuzz_examples`), the soak tier all of them.
"""

from __future__ import annotations

import os
import random
import re
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import NoReturn, TypeVar

import pytest

from beambench.common.resources import USER_DIR_ENV

pytest_plugins = ["longest_first"]  # make test's module order: the longest modules first

T = TypeVar("T")
E = TypeVar("E", bound=BaseException)
SHARED_ENV = "BEAMBENCH_SHARED"
REPO = Path(__file__).resolve().parents[1]


def shared_root() -> Path:
    """The shared folder: ``$BEAMBENCH_SHARED``, else ``../shared`` beside the checkout."""
    env = os.environ.get(SHARED_ENV)
    return Path(env).expanduser() if env else REPO.parent / "shared"


def shared_path(*parts: str) -> Path:
    """A path inside the shared folder (may not exist; see :func:`require_shared`)."""
    return shared_root().joinpath(*parts)


def skip_unless_ci(reason: str) -> NoReturn:
    """Skip the test with ``reason``; under CI (``$CI`` set) fail it instead: CI has what every test needs."""
    if os.environ.get("CI"):
        pytest.fail(f"CI must run this test: {reason}")
    pytest.skip(reason)


def require_shared(*parts: str) -> Path:
    """The existing shared file or folder ``parts``, or skip the test saying where it was looked for (fail in CI)."""
    path = shared_path(*parts)
    if not path.exists():
        skip_unless_ci(f"shared fixture {path} not found (set ${SHARED_ENV} or put the shared folder at ../shared)")
    return path


# the shipped release test with short windows: a real release session in about a second of sim
SHORT_RELEASE = (
    (REPO / "protocols" / "release_test.yaml")
    .read_text()
    .replace("settle_s: 0.5", "settle_s: 0.2")
    .replace("record_s: 1.0", "record_s: 0.5")
)


def record_sim_sessions(out: Path, protocols: dict[str, str]) -> dict[str, Path]:
    """Each protocol text run on the sim backend into ``out/<name>.h5`` (no viewer, no progress)."""
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.session.run import run_session

    made = {}
    for name, text in protocols.items():
        made[name] = out / f"{name}.h5"
        run_session(parse_protocol(text), text, "sim", made[name], rerun_mode="off", show_progress=False)
    return made


def unwritable_folder(tmp_path: Path) -> Path:
    """A folder no file can be created in: /proc/self even for root; chmod 500 for a normal user."""
    if os.geteuid() == 0:
        return Path("/proc/self")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    return ro


def wait_until(condition: Callable[[], T], timeout_s: float = 10.0, what: str = "", interval_s: float = 0.01) -> T:
    """Poll ``condition`` until it returns something true, and return that; fail after ``timeout_s`` naming
    ``what`` (generous: a loaded machine is slow, a quick one returns at once)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what or condition}")
        time.sleep(interval_s)


def holds_for(condition: Callable[[], object], duration_s: float, what: str = "", interval_s: float = 0.01) -> None:
    """Poll ``condition`` for ``duration_s``: it must be true at every poll (something that must keep holding
    while time passes, e.g. a watchdog kept fed past its timeout)."""
    end = time.monotonic() + duration_s
    while True:
        assert condition(), f"stopped holding: {what or condition}"
        if time.monotonic() >= end:
            return
        time.sleep(interval_s)


def pause(seconds: float, why: str) -> None:
    """Let ``seconds`` pass where the delay is the test's input, not a wait for something to happen: a stall of
    a given length, a stand-in's compute time, a peer's pacing. ``why`` says which."""
    if not why:
        raise ValueError("pause: say what the delay stands for")
    time.sleep(seconds)


def random_moment(rng: random.Random, lo_s: float, hi_s: float, why: str) -> float:
    """Let a random time in [``lo_s``, ``hi_s``] pass (drawn from ``rng``) and return it: a delay that is the test's
    input and varies, such as the moment a signal or fault is raced at (another each run, so repeated runs cover
    the window) or a stand-in's varying compute time."""
    delay = rng.uniform(lo_s, hi_s)
    pause(delay, why)
    return delay


def raised(call: Callable[[], object], kind: type[E]) -> E | None:
    """The ``kind`` exception ``call()`` raises, or None (a condition for :func:`wait_until`: a fault reported)."""
    try:
        call()
    except kind as exc:
        return exc
    return None


def descendants(pid: int) -> list[int]:
    """PIDs of ``pid``'s children, their children and so on (Linux /proc; empty elsewhere)."""
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            kids = [int(x) for x in (task / "children").read_text().split()]
        except OSError:
            continue
        for kid in kids:
            out += [kid, *descendants(kid)]
    return out


def process_alive(pid: int) -> bool:
    """``pid`` exists and is not a zombie (Linux /proc)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def cli(*args: str) -> tuple[int, str]:
    """Exit code and the combined output of one in-process CLI call; a traceback fails the test."""
    from typer.testing import CliRunner

    from beambench.cli import app

    res = CliRunner().invoke(app, list(args))
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise AssertionError(f"traceback instead of one line: {res.exception!r}") from res.exception
    return res.exit_code, res.output


def one_line_error(code: int, output: str, *words: str) -> str:
    """Exit 2 and exactly one ``beambench: error:`` line holding ``words``; no traceback."""
    errors = [ln for ln in output.splitlines() if ln.startswith("beambench: error:")]
    assert code == 2, output
    assert len(errors) == 1, output
    assert "Traceback" not in output, output
    assert len(errors[0]) < 400, errors[0]
    for w in words:
        assert w in errors[0], errors[0]
    return errors[0]


@contextmanager
def tmpfs(folder: Path, size: str) -> Iterator[Path]:
    """A tmpfs of ``size`` (mount's syntax: ``64k``, ``24m``) mounted at ``folder`` for the block; the test is
    skipped with the reason where mounting needs root it does not have."""
    folder.mkdir(exist_ok=True)
    try:
        res = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.SubprocessError) as exc:
        pytest.skip(f"cannot mount a tmpfs here ({exc})")
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (root needed): {res.stderr.strip()[:120]}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], capture_output=True, timeout=10)


SET_AXIS_STATE = 0x07  # CAN Simple command id (node 0)
_CLOSED_LOOP_REQUEST = re.compile(r"^ *(\d+\.\d+) +\d+ +7 +Tx +d 8 08 ", re.M)  # Set_Axis_State CLOSED_LOOP, node 0
_LOGGED_AT = re.compile(r"^ *(\d+\.\d+) ", re.M)


def armed_for(can_log: Path, for_s: float) -> bool:
    """A run's .asc CAN log (read as it is written) shows the closed-loop request and ``for_s`` of traffic after
    it: the motor is armed and turning (a condition for :func:`wait_until`)."""
    text = can_log.read_text(errors="replace") if can_log.exists() else ""
    armed = _CLOSED_LOOP_REQUEST.search(text)
    stamps = _LOGGED_AT.findall(text[armed.end() :]) if armed else []
    return bool(armed and stamps and float(stamps[-1]) - float(armed.group(1)) >= for_s)


def last_requested_state(can_log: Path) -> int | None:
    """The state the last Set_Axis_State frame on the bus asked for (from a run's own .asc CAN log)."""
    import can

    last = None
    with can.ASCReader(str(can_log)) as reader:
        for msg in reader:
            if msg.arbitration_id == SET_AXIS_STATE and not msg.is_remote_frame and len(msg.data) >= 4:
                last = int.from_bytes(bytes(msg.data[:4]), "little")
    return last


_SOAK = False


def fuzz_examples(n: int, default: int | None = None) -> int:
    """A Hypothesis test's example count: ``n`` in the soak tier; in the default run a fifth of it (at least 50),
    or ``default`` for a test whose examples take seconds each."""
    if _SOAK:
        return n
    return default if default is not None else min(n, max(50, n // 5))


def pytest_configure(config: pytest.Config) -> None:
    global _SOAK
    _SOAK = bool(config.getoption("--soak"))


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--soak", action="store_true", help="also run the soak tier (@pytest.mark.soak): more race repetitions"
    )


@pytest.hookimpl(tryfirst=True)  # before -m selects by marker
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if config.getoption("--soak"):
        for item in items:  # Hypothesis tests run again in the soak tier, at their full example counts
            if getattr(getattr(item, "obj", None), "is_hypothesis_test", False):
                item.add_marker(pytest.mark.soak)
        return
    soak = [item for item in items if item.get_closest_marker("soak")]
    if soak:
        config.hook.pytest_deselected(items=soak)
        items[:] = [item for item in items if not item.get_closest_marker("soak")]


def pytest_report_header(config: pytest.Config) -> str:
    if config.getoption("--soak"):
        return "soak tier: on"
    return "soak tier: off (more race repetitions; `make soak` or `pytest --soak -m soak` runs them, CI does)"


@pytest.fixture(autouse=True, scope="session")
def _private_user_dir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """Point the per-user folder at a temporary one for the whole run (subprocesses inherit it)."""
    old = os.environ.get(USER_DIR_ENV)
    path = tmp_path_factory.mktemp("beambench-user")
    os.environ[USER_DIR_ENV] = str(path)
    yield path
    if old is None:
        os.environ.pop(USER_DIR_ENV, None)
    else:
        os.environ[USER_DIR_ENV] = old
