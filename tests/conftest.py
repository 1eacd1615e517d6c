"""Shared test helpers.

- :func:`shared_path` / :func:`require_shared`: the shared fixtures (independent NatNet packets and captures, the
  ODrive DBC) live outside the repository, in ``$BEAMBENCH_SHARED`` if set, else ``../shared`` beside the checkout.
  Every test that reads them goes through here and skips with the reason when they are absent.
- Every test runs with ``$BEAMBENCH_USER_DIR`` pointing at a temporary folder, so nothing a test runs (calibrate,
  fit, …) writes into the real per-user folder.
- The soak tier (``@pytest.mark.soak``): more repetitions of a race check, at other random moments, than the
  default run's one or few. Deselected unless ``--soak`` is given (``make soak``; CI runs it after ``make test``).
  Every Hypothesis test belongs to it too: the default run makes a fifth of its examples (at least 50,
  :func:`fuzz_examples`), the soak tier all of them.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from beambench.common.resources import USER_DIR_ENV

SHARED_ENV = "BEAMBENCH_SHARED"
REPO = Path(__file__).resolve().parents[1]


def shared_root() -> Path:
    """The shared folder: ``$BEAMBENCH_SHARED``, else ``../shared`` beside the checkout."""
    env = os.environ.get(SHARED_ENV)
    return Path(env).expanduser() if env else REPO.parent / "shared"


def shared_path(*parts: str) -> Path:
    """A path inside the shared folder (may not exist; see :func:`require_shared`)."""
    return shared_root().joinpath(*parts)


def require_shared(*parts: str) -> Path:
    """The existing shared file or folder ``parts``, or skip the test saying where it was looked for."""
    path = shared_path(*parts)
    if not path.exists():
        pytest.skip(f"shared fixture {path} not found (set ${SHARED_ENV} or put the shared folder at ../shared)")
    return path


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
