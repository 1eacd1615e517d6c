"""The schema of a session file, checked when it is opened: an edited, damaged or foreign file fails here with
one line naming the HDF5 path and the problem, before any command reads, draws or writes anything.

Checked: the kind of every object (group or dataset, hard links only), dtypes and shapes, one row per sample in
every column of a stream (a closed file), labels that match their axis, host times that run forwards, step and
event times inside the recorded data's span (plus a margin), the ``/general`` text (the protocol there, JSON
entries, the protocol's YAML, the rig, the axis names) and ``/processing``. No dataset
may claim more bytes than the file holds, so nothing read from a file allocates beyond its size.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

import h5py
import numpy as np
import yaml

from beambench.acquisition.batch import ColumnSpec
from beambench.acquisition.streams import LOADCELL, MOCAP, MOTOR, loadcell_spec, mocap_spec, motor_spec

__all__ = ["AXIS", "SessionSchemaError", "check_schema"]

AXIS = re.compile(r"^[+-]?[xyz]$")
RIG = re.compile(r"^[a-z][a-z0-9_]{0,31}$")
NUMERIC = "biuf"  # bool, int, unsigned, float
TIME_MARGIN_NS = 60 * 10**9  # how far outside the data a step or event may lie (a step starts before its samples)
MAX_SPAN_NS = 7 * 86400 * 10**9  # a week: longer than any run; view draws the span in 1 s windows
SPAN_FACTOR = 20  # a stream's host times span at most this many times what its rows take at its nominal rate
BYTES_SLACK = 1 << 20  # rows a live writer has extended but not yet written (HDF5 reads them as zeros)
HOST_JITTER_NS = 50_000_000  # receive-time jitter: no row lies further behind any row before it
MAX_BACK_FRACTION = 0.25  # of a stream's steps between rows, at most this many may go back (jitter is now and then)
MIN_BACK_STEPS = 8  # so a short stream may show a few (a stream of 10 rows, 2 batches)
MAX_DEPTH = 12  # /general nesting (a hard link to a parent group would otherwise recurse forever)
MIN_STEP_FIELDS = {"index": "iu", "frequency_hz": "fiu", "t_start_ns": "i", "t_settled_ns": "i", "t_end_ns": "i"}
STEP_FIELDS = {**MIN_STEP_FIELDS, "status": "S", "direction": "S", "kind": "S", "repeat": "iu"}
EVENT_FIELDS = {"host_time_ns": "i", "kind": "S", "message": "S"}


class SessionSchemaError(ValueError):
    """One problem: ``where`` (an HDF5 path) and ``problem``; the reader turns it into its one-line error."""

    def __init__(self, where: str, problem: str) -> None:
        super().__init__(f"{where}: {problem}")


def check_schema(f: h5py.File, size: int, closed: bool = True) -> None:
    """Raise :class:`SessionSchemaError` on the first thing in ``f`` (a file of ``size`` bytes) that is not a
    beambench session as the readers expect it. ``closed``: the file was closed by its writer (not a file being
    written, nor one a killed run left open), so every column of a stream holds the same number of rows."""
    budget = size + BYTES_SLACK
    links = set(f)  # every link's name, a dangling one too (``name in f`` is False for those)
    for name in ("general", "acquisition", "processing"):
        if name in links:
            _hard_link(f, name)
            _kind(f[name], f"/{name}", h5py.Group)
    for name in ("steps", "events"):
        _hard_link(f, name)
        _kind(f[name], f"/{name}", h5py.Dataset)
    _check_general(f["general"], "/general", 0, budget)
    acquisition = _members(f["acquisition"], "/acquisition")
    spans = [_check_stream(g, f"/acquisition/{name}", budget, closed) for name, g in acquisition]
    steps = _table(f["steps"], "/steps", STEP_FIELDS, MIN_STEP_FIELDS, "status", budget)
    events = _table(f["events"], "/events", EVENT_FIELDS, EVENT_FIELDS, "kind", budget)
    _check_times(spans, steps, events)
    if "processing" in links:
        _check_processing(f["processing"], budget)


def _members(g: h5py.Group, where: str) -> list[tuple[str, Any]]:
    out = []
    for name in list(g):
        _hard_link(g, name, where)
        out.append((name, g[name]))
    return out


def _hard_link(g: h5py.Group, name: str, where: str = "") -> None:
    link = g.get(name, getlink=True)
    if not isinstance(link, h5py.HardLink):
        kind = "an external link" if isinstance(link, h5py.ExternalLink) else "a soft link"
        raise SessionSchemaError(f"{where}/{name}", f"{kind}; a session holds its data itself")


def _kind(obj: Any, where: str, kind: type) -> None:
    if not isinstance(obj, kind):
        got = "a group" if isinstance(obj, h5py.Group) else "a dataset"
        raise SessionSchemaError(where, f"{got}, expected a {'group' if kind is h5py.Group else 'dataset'}")


def _bounded(ds: h5py.Dataset, where: str, budget: int) -> None:
    nbytes = int(np.prod(ds.shape, dtype=np.float64) * ds.dtype.itemsize) if ds.shape is not None else 0
    if nbytes > budget:
        raise SessionSchemaError(where, f"claims {nbytes:,} bytes, more than the file holds ({budget - BYTES_SLACK:,})")


def _text(ds: h5py.Dataset, where: str) -> str:
    if ds.shape != () or (h5py.check_string_dtype(ds.dtype) is None and ds.dtype.kind != "S"):
        raise SessionSchemaError(where, f"a {ds.dtype} dataset of shape {ds.shape}, expected one text value")
    raw = ds[()]
    try:
        return raw.decode("utf-8") if isinstance(raw, bytes) else str(raw)
    except UnicodeDecodeError:
        raise SessionSchemaError(where, "not UTF-8 text") from None


# --- /general ----------------------------------------------------------------------------------------------
def _check_general(g: h5py.Group, where: str, depth: int, budget: int) -> None:
    if depth > MAX_DEPTH:
        raise SessionSchemaError(where, f"nested deeper than {MAX_DEPTH} groups (a link back to a parent?)")
    for name, item in _members(g, where):
        path = f"{where}/{name}"
        if isinstance(item, h5py.Group):
            _check_general(item, path, depth + 1, budget)
            continue
        _bounded(item, path, budget)
        text = _text(item, path)
        if item.attrs.get("encoding") == "json":
            try:
                json.loads(text)
            except ValueError as exc:
                raise SessionSchemaError(path, f"not JSON ({exc})") from None
    if depth == 0:
        _check_general_values(g, where)


def _check_general_values(g: h5py.Group, where: str) -> None:
    if not isinstance(g.get("protocol"), h5py.Dataset):  # every reader takes the rig, steps' plan … from it
        raise SessionSchemaError(f"{where}/protocol", "missing; a session holds the protocol it ran")
    for key in ("up_axis", "forward_axis", "geometry/up_axis", "geometry/forward_axis"):
        if isinstance(g.get(key), h5py.Dataset):
            value = _text(g[key], f"{where}/{key}").strip()
            if value and not AXIS.match(value):
                raise SessionSchemaError(f"{where}/{key}", f"{value[:20]!r} is not an axis (x, y, z, -x, +y …)")
    try:
        proto = yaml.safe_load(_text(g["protocol"], f"{where}/protocol"))
    except yaml.YAMLError as exc:
        problem = str(getattr(exc, "problem", None) or "syntax error")
        raise SessionSchemaError(f"{where}/protocol", f"not YAML ({problem})") from None
    protocol_rig = proto.get("rig") if isinstance(proto, dict) else None
    rig = _text(g["rig"], f"{where}/rig").strip() if isinstance(g.get("rig"), h5py.Dataset) else None
    if rig is not None and not RIG.match(rig):
        raise SessionSchemaError(f"{where}/rig", f"{rig[:20]!r} is not a rig name")
    # without /general/rig the protocol's rig: is the session's (what the readers take); only a contradiction is
    # refused
    if rig is not None and protocol_rig is not None and rig != protocol_rig:
        raise SessionSchemaError(f"{where}/rig", f"{rig[:20]!r}, but the protocol says rig: {str(protocol_rig)[:20]}")


# --- /acquisition ------------------------------------------------------------------------------------------
def _check_stream(g: Any, where: str, budget: int, closed: bool) -> tuple[int, int, int] | None:
    """The stream's checks; returns the first and last host time of its recorded rows and the longest span its
    rows allow, if it has rows."""
    _kind(g, where, h5py.Group)
    _check_stream_attrs(g, where)
    columns = dict(_members(g, where))
    _check_group_labels(g, where, len(columns))
    for name in ("host_time_ns", "device_time"):
        if name not in columns:
            raise SessionSchemaError(f"{where}/{name}", "missing")
    for name, ds in columns.items():
        path = f"{where}/{name}"
        _kind(ds, path, h5py.Dataset)
        _bounded(ds, path, budget)
        if ds.dtype.kind not in NUMERIC or ds.dtype.names is not None or ds.ndim < 1:
            raise SessionSchemaError(path, f"a {ds.dtype} dataset of shape {ds.shape}, expected numeric rows")
        _check_labels(ds, path)
    for name in ("host_time_ns", "device_time"):
        if columns[name].ndim != 1:
            raise SessionSchemaError(f"{where}/{name}", f"shape {columns[name].shape}, expected one value per row")
    for name, spec in _standard_columns(where).items():  # a standard stream's columns keep their row shape
        if name in columns and columns[name].ndim != 1 + len(spec.shape):
            want = "one value per row" if not spec.shape else f"rows of {len(spec.shape)} dimensions"
            raise SessionSchemaError(f"{where}/{name}", f"shape {columns[name].shape}, expected {want}")
    if columns["host_time_ns"].dtype.kind != "i":
        raise SessionSchemaError(f"{where}/host_time_ns", f"{columns['host_time_ns'].dtype}, expected int64 ns")
    if where == "/acquisition/mocap":
        _check_mocap(columns, where)
    if closed:
        _check_rows(columns, where)
    return _host_span(columns["host_time_ns"][()], f"{where}/host_time_ns", float(g.attrs.get("rate_hz", 0.0)))


def _standard_columns(where: str) -> dict[str, ColumnSpec]:
    """The columns of the standard stream at ``where`` (mocap, load cells, motor; none for another stream)."""
    name = where.rsplit("/", 1)[-1]
    specs = {MOCAP: lambda: mocap_spec(("m",)), LOADCELL: loadcell_spec, MOTOR: motor_spec}
    return specs[name]().columns if name in specs else {}


def _check_stream_attrs(g: h5py.Group, where: str) -> None:
    rate = g.attrs.get("rate_hz", 0.0)
    if not isinstance(rate, (int, float, np.number)) or not math.isfinite(float(rate)) or float(rate) < 0:
        raise SessionSchemaError(f"{where} rate_hz", f"{str(rate)[:20]!r} is not a rate (a number >= 0)")
    for key in ("up_axis", "forward_axis"):
        if key in g.attrs:
            value = g.attrs[key]
            value = value.decode("utf-8", "replace") if isinstance(value, bytes) else value
            if not isinstance(value, str) or not AXIS.match(value):
                raise SessionSchemaError(f"{where} {key}", f"{str(value)[:20]!r} is not an axis (x, y, z, -x, +y …)")


def _label_list(obj: Any, where: str) -> np.ndarray | None:
    """The ``labels`` attribute of ``obj`` as a list of names, None without one."""
    if "labels" not in obj.attrs:
        return None
    labels = np.asarray(obj.attrs["labels"])
    if labels.ndim != 1 or labels.dtype.kind not in "OSU" or any(not isinstance(x, (str, bytes)) for x in labels):
        raise SessionSchemaError(f"{where} labels", "expected a list of names")
    return labels


def _check_group_labels(g: h5py.Group, where: str, columns: int) -> None:
    """A group's ``labels`` (the writer puts none there; a tool may) name its columns, one each."""
    labels = _label_list(g, where)
    if labels is not None and len(labels) != columns:
        raise SessionSchemaError(f"{where} labels", f"{len(labels)} names for a group of {columns} columns")


def _check_labels(ds: h5py.Dataset, where: str) -> None:
    labels = _label_list(ds, where)
    if labels is None:
        return
    if ds.ndim < 2 or ds.shape[1] != len(labels):
        raise SessionSchemaError(f"{where} labels", f"{len(labels)} names for rows of shape {ds.shape[1:]}")


def _check_rows(columns: dict[str, h5py.Dataset], where: str) -> None:
    """Every column holds one row per sample: as many rows as ``host_time_ns``. The writer appends a batch to every
    column and closes the file at a flush, so a closed file whose columns differ was edited or damaged (a reader
    would otherwise cut every column to the shortest, silently). A file still open for writing may differ by the
    rows of the write in progress: there the reader keeps the rows every column holds."""
    rows = columns["host_time_ns"].shape[0]
    for name, ds in columns.items():
        if ds.shape[0] != rows:
            raise SessionSchemaError(
                f"{where}/{name}",
                f"{ds.shape[0]} rows, but host_time_ns has {rows}: one row per sample in every column",
            )


def _check_mocap(columns: dict[str, h5py.Dataset], where: str) -> None:
    data = columns.get("data")
    if data is None:
        raise SessionSchemaError(f"{where}/data", "missing")
    if data.ndim != 3 or data.shape[2] != 3 or data.dtype.kind != "f":
        raise SessionSchemaError(f"{where}/data", f"{data.dtype} of shape {data.shape}, expected (rows, markers, 3)")
    occ = columns.get("occluded")
    if occ is not None and (occ.ndim != 2 or occ.shape[1] != data.shape[1]):
        raise SessionSchemaError(f"{where}/occluded", f"shape {occ.shape}, expected (rows, {data.shape[1]})")


def _host_span(host: np.ndarray, where: str, rate_hz: float) -> tuple[int, int, int] | None:
    keep = host != 0  # rows a killed run extended but never wrote; a first row at 0 is the sim clock's start
    if len(keep) > 1 and not keep[0] and keep[1:].any():
        keep[0] = True
    real = host[keep]
    if len(real) == 0:
        return None
    _check_order(real, np.flatnonzero(keep), where)
    lo, hi = int(real.min()), int(real.max())
    allowed = MAX_SPAN_NS
    if rate_hz > 0:  # the rows' own duration bounds it (view draws the span in 1 s windows: no week of them)
        allowed = min(allowed, int(SPAN_FACTOR * len(real) / rate_hz * 1e9) + TIME_MARGIN_NS)
    if lo < 0 or hi - lo > allowed:
        rows = f"{len(real)} rows at {rate_hz:g} Hz" if rate_hz > 0 else f"{len(real)} rows"
        raise SessionSchemaError(where, f"spans {(hi - lo) * 1e-9:.6g} s with {rows}: not a run's host times")
    return lo, hi, allowed


def _check_order(real: np.ndarray, rows: np.ndarray, where: str) -> None:
    """Host times run forwards, with jitter: receive stamps (a sample's host time is its batch's receive time less
    its place in the batch) may fall a little behind earlier ones, now and then. Refused: a row more than
    ``HOST_JITTER_NS`` behind any row before it (so steps back add up: a stream that runs backwards in small steps
    fails as soon as it is 50 ms behind its latest time), and more than ``MAX_BACK_FRACTION`` of the steps between
    rows going back (jitter happens at some batch boundaries, not at every row)."""
    if len(real) < 2:
        return
    behind = np.maximum.accumulate(real) - real
    late = np.flatnonzero(behind > HOST_JITTER_NS)
    if len(late):
        i = int(late[0])
        raise SessionSchemaError(
            where,
            f"goes back in time at row {int(rows[i])} ({behind[i] * 1e-6:.6g} ms behind an earlier row); host times "
            f"only increase (up to {HOST_JITTER_NS // 10**6} ms jitter)",
        )
    back = int(np.count_nonzero(np.diff(real) < 0))
    if back > max(MIN_BACK_STEPS, MAX_BACK_FRACTION * (len(real) - 1)):
        raise SessionSchemaError(
            where,
            f"goes back in time at {back} of {len(real) - 1} steps between rows; receive jitter goes back now and "
            f"then (at most {MAX_BACK_FRACTION:.0%} of the steps), a host clock runs forwards",
        )


# --- /steps, /events and their times -----------------------------------------------------------------------
def _table(
    ds: h5py.Dataset, where: str, fields: dict[str, str], required: dict[str, str], key: str, budget: int
) -> Any:
    """The rows of a compound table with a key field set (``status`` / ``kind``): rows never written have it empty."""
    _bounded(ds, where, budget)
    names = ds.dtype.names or ()
    if ds.ndim != 1 or not names:
        raise SessionSchemaError(where, f"a {ds.dtype} dataset of shape {ds.shape}, expected a table of rows")
    key = "status" if "status" in fields else "kind"  # /steps: status (its kind column is optional); /events: kind
    for name, kinds in fields.items():
        if name not in names:
            if name in required or name == key:
                raise SessionSchemaError(where, f"no {name} column")
            continue
        if ds.dtype[name].kind not in kinds or ds.dtype[name].shape != ():
            raise SessionSchemaError(f"{where} {name}", f"of type {ds.dtype[name]}, expected {_kinds(kinds)}")
    rows = ds[()]
    return rows[rows[key] != b""]


def _kinds(kinds: str) -> str:
    return {"i": "an integer", "iu": "an integer", "fiu": "a number", "S": "fixed-length text"}.get(kinds, kinds)


def _check_times(spans: list[tuple[int, int, int] | None], steps: Any, events: Any) -> None:
    known = [s for s in spans if s is not None]
    if known:
        lo, hi = min(s[0] for s in known), max(s[1] for s in known)
        if hi - lo > max(s[2] for s in known):
            raise SessionSchemaError("/acquisition", f"the streams' host times lie {(hi - lo) * 1e-9:.6g} s apart")
    else:  # no samples (a run killed before its first batch): the steps' starts and the events bound the rest
        times = [*(steps["t_start_ns"] if len(steps) else ()), *(events["host_time_ns"] if len(events) else ())]
        lo, hi = (int(min(times)), int(max(times))) if times else (0, 0)
        if lo < 0 or hi - lo > MAX_SPAN_NS:
            raise SessionSchemaError("/steps, /events", f"times span {lo} … {hi} ns, not a run's host times")
    lo, hi = lo - TIME_MARGIN_NS, hi + TIME_MARGIN_NS
    for i, row in enumerate(steps):
        if not math.isfinite(float(row["frequency_hz"])):
            raise SessionSchemaError(f"/steps row {i} frequency_hz", "not a finite number")
        for name in ("t_start_ns", "t_settled_ns", "t_end_ns"):
            t = int(row[name])
            if (name != "t_start_ns" and t == -1) or lo <= t <= hi:
                continue
            raise SessionSchemaError(
                f"/steps row {i} {name}", f"{t} ns lies outside the recorded data ({_span(lo, hi)})"
            )
    if len(events):
        t = events["host_time_ns"]
        bad = np.flatnonzero((t < lo) | (t > hi))
        if len(bad):
            i = int(bad[0])
            raise SessionSchemaError(
                f"/events row {i}", f"{int(t[i])} ns lies outside the recorded data ({_span(lo, hi)})"
            )


def _span(lo: int, hi: int) -> str:
    return f"{lo} … {hi} ns, with a {TIME_MARGIN_NS // 10**9} s margin"


# --- /processing -------------------------------------------------------------------------------------------
def _check_processing(g: h5py.Group, budget: int) -> None:
    for name, table in _members(g, "/processing"):
        where = f"/processing/{name}"
        _kind(table, where, h5py.Group)
        members = _members(table, where)
        _check_group_labels(table, where, len(members))
        for key, ds in members:
            _kind(ds, f"{where}/{key}", h5py.Dataset)
            _bounded(ds, f"{where}/{key}", budget)
            if ds.dtype.names is not None or (
                ds.dtype.kind not in NUMERIC + "S" and h5py.check_string_dtype(ds.dtype) is None
            ):
                raise SessionSchemaError(f"{where}/{key}", f"a {ds.dtype} dataset, expected numbers or text")
        if "columns" in table.attrs:
            try:
                cols = json.loads(table.attrs["columns"])
            except (TypeError, ValueError):
                cols = None
            if not isinstance(cols, list) or not all(isinstance(c, str) for c in cols):
                raise SessionSchemaError(f"{where} columns", "expected a JSON list of column names")
            if sorted(cols) != sorted(key for key, _ in members):
                raise SessionSchemaError(
                    f"{where} columns", f"names {len(cols)} columns, the group holds {len(members)}"
                )
