"""Every row of a session is whole and in time order, or the file is refused in one line by every command that reads
a session (docs/safety.md, "Session files as input"): columns of a stream that disagree in length (nothing is cut
to the shortest), host clocks that run backwards in steps each inside the jitter allowance, a damaged superblock,
a ``labels`` attribute that names the wrong number of columns, a session without its protocol.

Real sessions (made once per module by the sim backend) are edited with h5py, as a user or a script would.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from beambench.cli import app
from beambench.sinks.session_file.reader import SessionFileError, read_session
from beambench.studies.twin_calibration.rig import session_targets
from beambench.studies.twin_calibration.targets import CalibrationInputError

CONTACT = "name: t\nsweep: {frequencies: [5, 10]}\nsettle_s: 0.2\nrecord_s: 0.3\n"


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    """A contact sweep of two steps, recorded by the sim backend, analysed once (so it has /processing)."""
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.session.run import run_session

    path = tmp_path_factory.mktemp("real") / "contact.h5"
    run_session(parse_protocol(CONTACT), CONTACT, "sim", path, rerun_mode="off", show_progress=False)
    code, out = _invoke(["analyze", str(path), "--figures", "none", "--out", f"{path}_report"])
    assert code == 0, out
    return path


def _invoke(args: list[str]) -> tuple[int, str]:
    res = CliRunner().invoke(app, args)
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise AssertionError(f"{args[0]}: traceback instead of one line: {res.exception!r}") from res.exception
    assert "Traceback" not in res.output, res.output
    return res.exit_code, res.output


def _read_api(path: Path) -> str:
    with pytest.raises(SessionFileError) as err:
        read_session(path)
    return str(err.value)


def _calibrate(path: Path) -> str:
    with pytest.raises(CalibrationInputError) as err:
        session_targets(path)
    return str(err.value)


# every command that reads a session: its one-line refusal (a CLI command's ``beambench: error:`` line, exit 2)
COMMANDS: dict[str, Callable[[Path, Path], list[str]]] = {
    "analyze": lambda p, tmp: ["analyze", str(p), "--out", str(tmp / "report"), "--figures", "none"],
    "compare": lambda p, tmp: ["compare", str(p), str(p), "--out", str(tmp / "cmp"), "--figures", "none"],
    "view": lambda p, tmp: ["view", str(p), "--rerun", "save", "--out", str(tmp / "v.rrd")],
    "fit": lambda p, tmp: ["fit", str(p), "--max-iters", "1", "--no-write", "--out", str(tmp / "fit")],
    "calibrate sim": lambda p, tmp: ["calibrate", "sim", str(p), "--out", str(tmp / "cal")],
}
READERS = [*COMMANDS, "read_session", "session_targets"]


def _refusal(reader: str, path: Path, tmp: Path) -> str:
    if reader == "read_session":
        return _read_api(path)
    if reader == "session_targets":
        return _calibrate(path)
    code, out = _invoke(COMMANDS[reader](path, tmp))
    errors = [ln for ln in out.splitlines() if ln.startswith("beambench: error:")]
    assert code == 2 and len(errors) == 1 and len(errors[0]) < 400, f"{reader}: exit {code}: {out[-1500:]}"
    return errors[0]


def _edited(session: Path, tmp: Path, edit: Callable[[h5py.File], None]) -> Path:
    path = tmp / "edited.h5"
    shutil.copy(session, path)
    with h5py.File(path, "r+") as f:
        edit(f)
    return path


def _rows(path: str, n: int) -> Callable[[h5py.File], None]:
    """Rewrite the dataset at ``path`` with ``n`` rows: cut, or its rows repeated."""

    def edit(f: h5py.File) -> None:
        old = f[path][()]
        del f[path]
        f.create_dataset(path, data=np.concatenate([old] * (n // len(old) + 1))[:n])

    return edit


# --- 1. columns of one stream that disagree in length ---------------------------------------------------------
LENGTHS = {  # the dataset edited, and the rows it is given (None: its rows less one; "double": twice its rows)
    "acquisition/mocap/data": 10,
    "acquisition/loadcell/device_time": 100,
    "acquisition/mocap/occluded": 5,
    "acquisition/loadcell/data": "double",
    "acquisition/motor/velocity": None,
    "acquisition/mocap/host_time_ns": None,
}


@pytest.mark.parametrize("dataset", sorted(LENGTHS))
@pytest.mark.parametrize("reader", READERS)
def test_a_column_of_another_length_is_refused_naming_it_and_both_lengths(dataset, reader, session, tmp_path):
    with h5py.File(session, "r") as f:
        rows = len(f[dataset])
        others = {len(ds) for name, ds in f[dataset.rsplit("/", 1)[0]].items() if name != dataset.rsplit("/", 1)[1]}
    (n_others,) = others  # the session as written: one length in every column
    given = LENGTHS[dataset]
    n = rows * 2 if given == "double" else rows - 1 if given is None else given
    path = _edited(session, tmp_path, _rows(dataset, n))
    before = path.read_bytes()
    line = _refusal(reader, path, tmp_path)
    assert re.search(rf"\b{n} rows|has {n}\b", line) and re.search(rf"\b{n_others}\b", line), line  # both lengths
    stream, column = dataset.rsplit("/", 1)
    assert f"/{dataset}" in line or (column == "host_time_ns" and f"/{stream}/" in line), line
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no report, recording or fit folder


def test_a_file_a_killed_writer_left_open_reads_the_rows_every_column_holds(session, tmp_path):
    """The one place columns may differ: a file still open for writing (a live run, or a run killed between two
    appends). There the reader keeps the rows every column holds, as before."""
    path = tmp_path / "killed.h5"
    shutil.copy(session, path)
    rows = len(read_session(path).streams["mocap"])
    script = f"""
import os, h5py, numpy as np
f = h5py.File({str(path)!r}, "r+", libver="latest")
f.swmr_mode = True
g = f["acquisition/mocap"]
for name, ds in g.items():
    if name == "data":
        continue  # killed before this column's rows were appended
    ds.resize((ds.shape[0] + 5, *ds.shape[1:]))
    if name == "host_time_ns":
        ds[-5:] = ds[-6] + np.arange(1, 6) * 2_777_778
f.flush()
os._exit(0)
"""
    subprocess.run([sys.executable, "-c", script], check=True, timeout=60)
    s = read_session(path)
    assert len(s.streams["mocap"]) == rows
    assert {len(v) for v in s.streams["mocap"].columns.values()} == {rows}


# --- 2. host clocks that run backwards ----------------------------------------------------------------------
def _host(stream: str, make: Callable[[np.ndarray], np.ndarray]) -> Callable[[h5py.File], None]:
    def edit(f: h5py.File) -> None:
        ds = f[f"acquisition/{stream}/host_time_ns"]
        ds[...] = make(ds[()])

    return edit


def _backwards_in_small_steps(h: np.ndarray) -> np.ndarray:
    rng = np.random.default_rng(3)
    steps = rng.uniform(1e6, 30e6, len(h) - 1).astype(np.int64)  # each 1–30 ms back, far inside the allowance
    return np.concatenate([[h[-1]], h[-1] - np.cumsum(steps)])


def _sawtooth(h: np.ndarray) -> np.ndarray:
    """Forwards 2 ms, back 1 ms, over and over: never 50 ms behind, but half the steps go back."""
    steps = np.where(np.arange(len(h) - 1) % 2 == 0, 2_000_000, -1_000_000)
    return np.concatenate([[h[0]], h[0] + np.cumsum(steps)])


BACKWARDS = {
    "mocap reversed": ("mocap", lambda h: h[::-1].copy()),
    "loadcell reversed": ("loadcell", lambda h: h[::-1].copy()),
    "motor reversed": ("motor", lambda h: h[::-1].copy()),
    "mocap backwards in random small steps": ("mocap", _backwards_in_small_steps),
    "loadcell sawtooth": ("loadcell", _sawtooth),
}


@pytest.mark.parametrize("case", sorted(BACKWARDS))
@pytest.mark.parametrize("reader", ["analyze", "view", "read_session"])
def test_a_host_clock_that_runs_backwards_is_refused(case, reader, session, tmp_path):
    stream, make = BACKWARDS[case]
    path = _edited(session, tmp_path, _host(stream, make))
    line = _refusal(reader, path, tmp_path)
    assert f"/acquisition/{stream}/host_time_ns" in line and "back in time" in line, line


def _jitter(h: np.ndarray) -> np.ndarray:
    """What receive stamps do: now and then (a batch boundary, every 20th row here) a stamp falls up to 40 ms
    behind the one before, and the clock goes on."""
    out = h.copy()
    rng = np.random.default_rng(5)
    for i in range(20, len(h), 20):
        out[i] = out[i - 1] - int(rng.uniform(1e6, 40e6))
    return out


def test_receive_jitter_now_and_then_still_reads(session, tmp_path):
    path = _edited(session, tmp_path, _host("mocap", _jitter))
    s = read_session(path)
    assert (np.diff(s.streams["mocap"].host_time_ns) < 0).sum() >= 10  # the jitter is there, and read
    code, out = _invoke(["analyze", str(path), "--out", str(tmp_path / "r"), "--no-write", "--figures", "none"])
    assert code == 0, out


# --- 4. damaged superblock, labels, the protocol, /processing tables -----------------------------------------
def _flip(offset: int) -> Callable[[Path], None]:
    def damage(path: Path) -> None:
        data = bytearray(path.read_bytes())
        data[offset] ^= 0xFF
        path.write_bytes(bytes(data))

    return damage


DAMAGED: dict[str, tuple[Callable[[h5py.File], None] | None, Callable[[Path], None] | None, str]] = {
    # name: (an h5py edit, a byte edit, what the line names)
    "superblock version": (None, _flip(8), "not a readable"),
    "superblock offset size": (None, _flip(9), "not a readable"),
    "superblock end of file": (None, _flip(30), "edited.h5"),
    "group labels, 3 for the plate's 4 channels": (
        lambda f: f["acquisition/loadcell"].attrs.__setitem__("labels", ["a", "b", "c"]),
        None,
        "/acquisition/loadcell labels",
    ),
    "plate data labels, 5 for 4 channels": (
        lambda f: f["acquisition/loadcell/data"].attrs.__setitem__("labels", ["a", "b", "c", "d", "e"]),
        None,
        "/acquisition/loadcell/data labels",
    ),
    "processing table labels of the wrong length": (
        lambda f: f["processing/steps"].attrs.__setitem__("labels", ["a", "b", "c", "d"]),
        None,
        "/processing/steps labels",
    ),
    "processing columns attribute naming others": (
        lambda f: f["processing/steps"].attrs.__setitem__("columns", '["a", "b"]'),
        None,
        "/processing/steps columns",
    ),
    "no protocol": (lambda f: f["general"].__delitem__("protocol"), None, "/general/protocol"),
}


@pytest.mark.parametrize("case", sorted(DAMAGED))
@pytest.mark.parametrize("reader", READERS)
def test_a_damaged_or_incomplete_session_is_one_line(case, reader, session, tmp_path):
    edit, damage, named = DAMAGED[case]
    path = _edited(session, tmp_path, edit or (lambda f: None))
    if damage is not None:
        damage(path)
    line = _refusal(reader, path, tmp_path)
    assert named in line and "\n" not in line, line


def test_a_processing_table_whose_columns_differ_in_length_is_one_line(session, tmp_path):
    from beambench.sinks.session_file.reader import read_processing

    assert len(read_processing(session, "steps")) == 2  # the analysed session: one row per step
    path = _edited(session, tmp_path, _rows("processing/steps/frequency_hz", 1))
    with pytest.raises(SessionFileError, match=r"/processing/steps/frequency_hz: 1 rows, but \w+ has 2"):
        read_processing(path, "steps")
