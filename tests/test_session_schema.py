"""Edited, damaged or junk session files never reach a traceback: the schema check on open refuses them with one
line naming the HDF5 path and the problem, exit 2, in every command that opens a session (analyze, view, fit,
calibrate), before anything is written or allocated beyond what the file holds.

Real sessions (made once per module by the sim backend, short protocols) are edited the ways a user, a script or
a broken copy would: each named case below, then Hypothesis mutations (delete, replace, reshape, retype
datasets; edit values and attributes; links; truncation; junk bytes).
"""

from __future__ import annotations

import shutil
import tracemalloc
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from beambench.cli import app
from beambench.sinks.session_file.reader import SessionFileError, read_session
from beambench.studies.twin_calibration.rig import session_targets
from beambench.studies.twin_calibration.targets import CalibrationInputError
from conftest import SHORT_RELEASE, fuzz_examples, record_sim_sessions

CONTACT = "name: t\nsweep: {frequencies: [5, 10]}\nsettle_s: 0.2\nrecord_s: 0.3\n"


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> dict[str, Path]:
    """A contact sweep (two steps) and a release test, recorded by the sim backend."""
    return record_sim_sessions(tmp_path_factory.mktemp("real"), {"contact": CONTACT, "release": SHORT_RELEASE})


def _commands(path: Path, rig: str) -> list[list[str]]:
    """analyze, view and fit on ``path`` (fit refuses a contact session in one line: that is checked too)."""
    return [
        ["analyze", str(path), "--out", f"{path}_report", "--figures", "none"],
        ["view", str(path), "--rerun", "save", "--out", f"{path}.rrd"],
        ["fit", str(path), "--max-iters", "1", "--no-write", "--out", f"{path}_fit"],
    ]


def _invoke(args: list[str]) -> tuple[int, str]:
    res = CliRunner().invoke(app, args)
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise AssertionError(f"{args[0]}: traceback instead of one line: {res.exception!r}") from res.exception
    assert "Traceback" not in res.output, res.output
    return res.exit_code, res.output


def _one_line(code: int, output: str, command: str) -> str:
    errors = [ln for ln in output.splitlines() if ln.startswith("beambench: error:")]
    assert code == 2, f"{command}: exit {code}: {output[-1500:]}"
    assert len(errors) == 1 and len(errors[0]) < 400, f"{command}: {output[-1500:]}"
    return errors[0]


def _calibrate_reads(path: Path) -> str | None:
    """What ``calibrate sim SESSION`` does with the session before it searches: its one-line error, or None."""
    try:
        session_targets(path)
    except CalibrationInputError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 400, str(exc)
        return str(exc)
    return None


# --- the cases of the issue, one by one --------------------------------------------------------------------
def _replace(f: h5py.File, path: str, data: Any) -> None:
    del f[path]
    f.create_dataset(path, data=data)


def _set_steps(f: h5py.File, field: str, value: int) -> None:
    rows = f["steps"][()]
    rows[field] = value
    f["steps"][...] = rows


def _drop_field(f: h5py.File, path: str, field: str) -> None:
    old = f[path][()]
    names = [n for n in old.dtype.names if n != field]
    new = np.zeros(len(old), dtype=[(n, old.dtype[n]) for n in names])
    for n in names:
        new[n] = old[n]
    _replace(f, path, new)


def _shuffle(f: h5py.File, path: str) -> None:
    ds = f[path]
    values = ds[()]
    np.random.default_rng(0).shuffle(values)
    ds[...] = values


DAYS_6 = 6 * 86400 * 10**9


def _shift(f: h5py.File, path: str, ns: int) -> None:
    f[path][...] = f[path][()] + ns


def _mocap(f: h5py.File, how: str) -> None:
    data = f["acquisition/mocap/data"][()]
    _replace(f, "acquisition/mocap/data", data.reshape(len(data), -1) if how == "reshape" else data.astype("S8"))


def _text(f: h5py.File, path: str, text: str) -> None:
    del f[path]
    f.create_dataset(path, data=text, dtype=h5py.string_dtype())


CASES: dict[str, tuple[Any, str]] = {  # name: (edit, what the one line names)
    "events_of_numbers": (lambda f: _replace(f, "events", np.arange(5.0)), "/events"),
    "steps_of_numbers": (lambda f: _replace(f, "steps", np.arange(5)), "/steps"),
    "steps_a_group": (lambda f: (f.__delitem__("steps"), f.create_group("steps")), "/steps"),
    "steps_without_t_end": (lambda f: _drop_field(f, "steps", "t_end_ns"), "t_end_ns"),
    "processing_a_dataset": (lambda f: _replace(f, "processing", np.arange(3)), "/processing"),
    "labels_of_wrong_length": (
        lambda f: f["acquisition/mocap/data"].attrs.__setitem__("labels", ["a", "b"]),
        "/acquisition/mocap/data labels",
    ),
    "up_axis_q": (lambda f: f["acquisition/mocap"].attrs.__setitem__("up_axis", "q"), "up_axis"),
    "geometry_up_axis_q": (lambda f: _text(f, "general/geometry/up_axis", "q"), "/general/geometry/up_axis"),
    "mocap_reshaped": (lambda f: _mocap(f, "reshape"), "/acquisition/mocap/data"),
    "mocap_as_strings": (lambda f: _mocap(f, "strings"), "/acquisition/mocap/data"),
    "mocap_frame_as_columns": (  # Hypothesis found it: sync's frame offset took a 2-D column (a TypeError)
        lambda f: _replace(f, "acquisition/mocap/frame", f["acquisition/mocap/frame"][()].reshape(-1, 1)),
        "/acquisition/mocap/frame",
    ),
    "loadcell_seq_as_columns": (
        lambda f: _replace(f, "acquisition/loadcell/seq", f["acquisition/loadcell/seq"][()].reshape(-1, 1)),
        "/acquisition/loadcell/seq",
    ),
    "step_end_at_2^62": (lambda f: _set_steps(f, "t_end_ns", 2**62), "t_end_ns"),
    "step_start_at_-2^62": (lambda f: _set_steps(f, "t_start_ns", -(2**62)), "t_start_ns"),
    "host_time_last_at_2^62": (
        lambda f: f["acquisition/mocap/host_time_ns"].__setitem__(-1, 2**62),
        "/acquisition/mocap/host_time_ns",
    ),
    "host_time_spanning_a_week": (  # every row kept in order: view drew 600 000 one-second windows (78 s)
        lambda f: f["acquisition/mocap/host_time_ns"].__setitem__(-1, f["acquisition/mocap/host_time_ns"][0] + DAYS_6),
        "/acquisition/mocap/host_time_ns",
    ),
    "streams_days_apart": (lambda f: _shift(f, "acquisition/loadcell/host_time_ns", DAYS_6), "/acquisition:"),
    "host_time_shuffled": (lambda f: _shuffle(f, "acquisition/mocap/host_time_ns"), "host_time_ns"),
    "protocol_not_yaml": (lambda f: _text(f, "general/protocol", "a: [b\n  : c: {"), "/general/protocol"),
    "rig_contradicts_protocol": (lambda f: _text(f, "general/rig", "walker"), "/general/rig"),
    "a_dataset_resized_beyond_the_file": (
        lambda f: f["acquisition/motor/position"].resize((10**11,)),
        "/acquisition/motor/position",
    ),
    "an_external_link": (
        lambda f: (
            f.__delitem__("acquisition/motor/position"),
            f.__setitem__("acquisition/motor/position", h5py.ExternalLink("/etc/hostname", "/x")),
        ),
        "external link",
    ),
    "general_linked_to_itself": (lambda f: f["general/identity"].__setitem__("loop", f["general"]), "/general"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_each_edited_session_is_one_line_exit_2_in_every_command(case, sessions, tmp_path):
    edit, named = CASES[case]
    rig = "release" if case == "rig_contradicts_protocol" else "contact"  # a release session that says walker
    path = tmp_path / f"{case}.h5"
    shutil.copy(sessions[rig], path)
    with h5py.File(path, "r+") as f:
        edit(f)
    before = path.read_bytes()
    with pytest.raises(SessionFileError) as err:
        read_session(path)
    assert named in str(err.value) and "\n" not in str(err.value), str(err.value)
    for args in _commands(path, rig):
        line = _one_line(*_invoke(args), args[0])
        assert named in line and line.count(str(path)) == 1, line
    line = _one_line(*_invoke(["calibrate", "sim", str(path), "--out", str(tmp_path / "cal")]), "calibrate")
    assert named in line, line
    assert path.read_bytes() == before  # nothing written into the session
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no report, recording or fit folder


def test_a_release_session_without_its_rig_entry_is_read_as_its_protocol_says(sessions, tmp_path):
    """/general/rig missing: the protocol's rig: is the session's (a release session is analysed as one)."""
    from beambench.analysis.session_analysis import session_rig

    path = tmp_path / "no_rig.h5"
    shutil.copy(sessions["release"], path)
    with h5py.File(path, "r+") as f:
        del f["general/rig"]
    s = read_session(path)
    assert "rig" not in s.general and session_rig(dict(s.general)) == "release"
    code, out = _invoke(["analyze", str(path), "--out", str(tmp_path / "r"), "--no-write", "--figures", "none"])
    assert code == 0 and "Traceback" not in out, out


def test_junk_after_the_hdf5_signature_is_one_line(sessions, tmp_path):
    data = sessions["contact"].read_bytes()
    path = tmp_path / "junk.h5"
    path.write_bytes(data[:8] + bytes(range(256)) * 4 + data[8 + 1024 :])
    for args in _commands(path, "contact"):
        _one_line(*_invoke(args), args[0])
    assert _calibrate_reads(path) is not None


def test_the_real_sessions_pass_and_read_whole(sessions):
    for rig, path in sessions.items():
        s = read_session(path)
        assert len(s.steps) == (2 if rig == "contact" else 1) and len(s.streams["mocap"]) > 100
        assert (s.steps["t_end_ns"] > s.steps["t_start_ns"]).all()


def test_a_killed_runs_unended_step_and_unwritten_rows_still_read(sessions, tmp_path):
    """What a killed run leaves is a session, not junk: a step with no end (-1) and rows of zeros at the end."""
    path = tmp_path / "killed.h5"
    shutil.copy(sessions["contact"], path)
    with h5py.File(path, "r+") as f:
        _set_steps(f, "t_end_ns", -1)
        rows = len(f["acquisition/mocap/host_time_ns"])
        for ds in f["acquisition/mocap"].values():  # the writer extends every column of a batch: zeros, never written
            ds.resize((rows + 50, *ds.shape[1:]))
    s = read_session(path)
    assert (s.steps["t_end_ns"] == -1).all() and len(s.streams["mocap"]) == rows


# --- Hypothesis: random edits of real sessions ---------------------------------------------------------------
SPECIAL = [0, -1, 1, 2**62, -(2**62), np.iinfo(np.int64).max, float("nan"), float("inf"), -1e300, 1e-320]
ATTR_VALUES = ["q", "", "-y", 0, -1.0, float("nan"), 1e300, ["a", "b"], ["m"] * 7, "[1, 2", b"\xff\xfe"]
ATTR_NAMES = ["up_axis", "forward_axis", "rate_hz", "labels", "encoding", "columns", "unit", "frame_unit"]
TEXTS = ["", "q", "{", "a: [b", "rig: release", "rig: walker", "- 1\n- 2", "rig: [x]", "\x00\xff", "null", "1e999"]
BULK = ("general/identity", "general/versions")  # most of the objects, read as text only: drawn less often
RETYPES = ["i1", "u2", "f4", "f8", "i8", "?", "S8"]


def _objects(path: Path) -> list[str]:
    names: list[str] = []
    with h5py.File(path, "r") as f:
        f.visit(names.append)
    return sorted(names)


@st.composite
def _edits(draw: Any, objects: list[str]) -> list[tuple]:
    out: list[tuple] = []
    for _ in range(draw(st.integers(1, 3))):
        op = draw(
            st.sampled_from(
                [
                    "delete",
                    "replace",
                    "reshape",
                    "retype",
                    "values",
                    "shuffle",
                    "attr",
                    "text",
                    "resize",
                    "link",
                    "drop_field",
                    "truncate",
                    "junk",
                ]
            )
        )
        target = draw(st.sampled_from([o for o in objects if not o.startswith(BULK)]) | st.sampled_from(objects))
        if op == "values":
            out.append((op, target, draw(st.integers(0, 10**6)), draw(st.sampled_from(SPECIAL))))
        elif op == "attr":
            out.append((op, target, draw(st.sampled_from(ATTR_NAMES)), draw(st.sampled_from([*ATTR_VALUES, None]))))
        elif op == "text":
            out.append(
                (
                    op,
                    target,
                    draw(st.sampled_from(TEXTS) | st.text(st.characters(exclude_characters="\x00"), max_size=40)),
                )
            )
        elif op in ("truncate", "junk"):
            out.append((op, draw(st.floats(0.0, 1.0)), draw(st.binary(min_size=1, max_size=64))))
        else:
            out.append((op, target, draw(st.integers(0, 10**6)), draw(st.sampled_from(RETYPES))))
    return out


def _edit(f: h5py.File, edit: tuple) -> None:
    op, target = edit[0], edit[1]
    try:
        obj = f[target]
    except (KeyError, OSError):  # an earlier edit removed it or made it a link
        return
    if op == "delete":
        del f[target]
    elif op == "link":
        del f[target]
        f[target] = h5py.SoftLink("/nowhere") if edit[2] % 2 else h5py.ExternalLink("/etc/hostname", "/x")
    elif op == "attr":
        _, _, name, value = edit
        if value is None:
            obj.attrs.pop(name, None) if name in obj.attrs else None
        else:
            obj.attrs[name] = value
    elif op == "text":
        if isinstance(obj, h5py.Dataset):
            del f[target]
            text = edit[2]
            if "\x00" in text:  # HDF5's variable-length strings cannot hold a NUL: fixed-length bytes can
                f.create_dataset(target, data=np.bytes_(text.encode("latin-1")))
            else:
                f.create_dataset(target, data=text, dtype=h5py.string_dtype())
    elif isinstance(obj, h5py.Dataset):
        _edit_dataset(f, target, obj, edit)
    elif op == "replace":
        del f[target]
        f.create_dataset(target, data=np.arange(edit[2] % 7).astype(edit[3]))


def _edit_dataset(f: h5py.File, target: str, ds: h5py.Dataset, edit: tuple) -> None:
    op, k = edit[0], edit[2]
    if op == "resize" and ds.maxshape and ds.maxshape[0] is None:
        ds.resize((10 ** (k % 12), *ds.shape[1:]))
        return
    if ds.size * ds.dtype.itemsize > 1 << 26:  # resized by an earlier edit: not read here either
        return
    data = np.asarray(ds[()])
    attrs = dict(ds.attrs)
    if op == "values" and data.size:
        flat = data.reshape(-1)
        field = ds.dtype.names[k % len(ds.dtype.names)] if ds.dtype.names else None
        try:
            if field is not None:
                flat[field][k % len(flat)] = edit[3]
            else:
                flat[k % len(flat)] = edit[3]
        except (TypeError, ValueError, OverflowError):
            return
        ds[...] = flat.reshape(data.shape)
        return
    if op == "shuffle" and data.ndim:
        np.random.default_rng(k).shuffle(data)
        ds[...] = data
        return
    if op == "drop_field" and ds.dtype.names:
        _drop_field(f, target, ds.dtype.names[k % len(ds.dtype.names)])
        return
    if op == "reshape" and data.ndim:
        new = data.reshape(-1) if data.ndim > 1 else data.reshape(-1, 1)
    elif op == "retype" and not ds.dtype.names:
        try:
            new = data.astype(edit[3])
        except (TypeError, ValueError):  # text that is not a number: zeros of the new type, same shape
            new = np.zeros(data.shape, edit[3])
    elif op == "replace":
        new = np.arange(k % 7).astype(edit[3])
    else:
        return
    del f[target]
    f.create_dataset(target, data=new)
    f[target].attrs.update(attrs)


def _damage(path: Path, edit: tuple) -> None:
    op, at, junk = edit
    data = path.read_bytes()
    i = int(at * len(data))
    path.write_bytes(data[:i] if op == "truncate" else data[:i] + junk + data[i + len(junk) :])


def _apply(path: Path, edits: list[tuple]) -> None:
    with h5py.File(path, "r+") as f:
        for e in edits:
            if e[0] not in ("truncate", "junk"):
                _edit(f, e)
    for e in edits:
        if e[0] in ("truncate", "junk"):
            _damage(path, e)


_BASE: dict[str, list[str]] = {}


@settings(
    max_examples=fuzz_examples(100, default=8),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.data_too_large],
)
@given(data=st.data())
def test_random_edits_of_real_sessions_are_read_or_refused_in_one_line(sessions, tmp_path_factory, data):
    rig = data.draw(st.sampled_from(sorted(sessions)))
    objects = _BASE.setdefault(rig, _objects(sessions[rig]))
    edits = data.draw(_edits(objects))
    path = tmp_path_factory.mktemp("fuzz") / "edited.h5"
    shutil.copy(sessions[rig], path)
    _apply(path, edits)
    size = path.stat().st_size
    tracemalloc.start()
    try:
        read_session(path)
    except SessionFileError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 400, str(exc)
        refused = True
    else:
        refused = False
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert peak < 4 * size + (32 << 20), f"reading a {size}-byte file allocated {peak} bytes"
    for args in _commands(path, rig):
        code, output = _invoke(args)
        if refused or code != 0:
            _one_line(code, output, args[0])
    reason = _calibrate_reads(path)
    assert not refused or reason is not None
