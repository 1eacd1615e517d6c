"""The HDF5 session file's reader: checks a file is a whole session before HDF5 sees it, opens it in SWMR mode
(a file being written, or cut off by a kill, reads too) and returns a :class:`SessionFile`. The layout is the
writer's (:mod:`beambench.sinks.session_file.writer`).
"""

from __future__ import annotations

import ctypes
import glob
import json
import os
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

from beambench.acquisition.batch import ColumnSpec, Frame, StreamSpec
from beambench.acquisition.control.speed_controller import track_spec
from beambench.acquisition.streams import loadcell_spec, motor_spec
from beambench.common.inputs import check_input_file
from beambench.common.yaml_config import ConfigError
from beambench.sinks.session_file.schema import SessionSchemaError, check_schema

if TYPE_CHECKING:  # tables are built where a session is read: a run that writes one never loads pandas
    import pandas as pd
    import xarray as xr

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
SESSION_GROUPS = ("general", "acquisition", "steps", "events")


class SessionFileError(ConfigError, OSError):
    """A session file cannot be created or is not a readable session (truncated, not HDF5, wrong layout).

    One line, naming the file. Also an :class:`OSError`, so callers that catch read errors catch it too.
    """


def _stored_eof(path: Path, size: int) -> int | None:
    """The end-of-file address a version 2/3 superblock records (HDF5 "libver latest"), or None."""
    with path.open("rb") as fh:
        offset = 0
        while offset + 8 <= size:  # the signature sits at 0, 512, 1024, 2048 … (after a user block)
            fh.seek(offset)
            if fh.read(8) == HDF5_SIGNATURE:
                head = fh.read(4)  # version, size of offsets, size of lengths, flags
                if len(head) < 4 or head[0] not in (2, 3) or head[1] != 8:
                    return None
                addrs = fh.read(8 * 4)  # base, superblock extension, end of file, root object header
                if len(addrs) < 32:
                    return 0x7FFFFFFFFFFFFFFF  # a cut superblock: certainly truncated
                base, _ext, eof, _root = struct.unpack("<4Q", addrs)
                return base + eof
            offset = 512 if offset == 0 else offset * 2
    return None


def check_session_file(path: str | Path) -> bool:
    """Fail fast, with one line, on anything that is not a complete HDF5 session file. True if the file was closed
    by its writer; False if it is still open for writing (a live run, or a run killed before it closed the file).

    A SWMR reader retries metadata reads on a truncated file without end, so this runs before it: the size,
    the HDF5 signature, then a plain (non-SWMR) open, which HDF5 refuses at once on a truncated file. A file
    still open for writing (or left so by a killed run) refuses the plain open; then the superblock's
    recorded end of file is compared with the size instead.
    """
    path = Path(path)
    check_input_file(path, "session file", None, SessionFileError)  # a folder, a FIFO, a device: one line
    try:
        size = path.stat().st_size
        with path.open("rb") as fh:
            head = fh.read(8)
    except OSError as exc:
        raise SessionFileError(f"{path}: cannot read the session ({exc.strerror or exc})") from None
    if size < 64 or (head != HDF5_SIGNATURE and _stored_eof(path, size) is None):
        raise SessionFileError(f"{path}: not a beambench session file (not HDF5{', empty' if size == 0 else ''})")
    try:
        with h5py.File(path, "r") as f:
            missing = [g for g in SESSION_GROUPS if g not in f]
    except RuntimeError as exc:  # a damaged superblock ("bad superblock version number") is h5py's RuntimeError
        raise SessionFileError(f"{path}: not a readable HDF5 file ({str(exc)[:120]})") from None
    except OSError as exc:
        text = str(exc)
        if "truncated" in text:
            raise SessionFileError(f"{path}: truncated ({size} bytes): an incomplete copy or a full disk?") from None
        if "already open for write" not in text and "lock" not in text:
            raise SessionFileError(f"{path}: not a readable HDF5 file ({text[:120]})") from None
        eof = _stored_eof(path, size)
        if eof is not None and size < eof:
            raise SessionFileError(f"{path}: truncated ({size} of {eof} bytes): an incomplete copy?") from None
        return False  # being written, or killed mid-run: the SWMR reader handles it
    if missing:
        raise SessionFileError(f"{path}: not a beambench session (no /{missing[0]} in the file)")
    return True


SWMR_READ_ATTEMPTS = 20  # HDF5's default (100, with growing waits) makes a cut file look like a hang


def _find_set_read_attempts() -> Callable[[int, int], int] | None:
    """``H5Pset_metadata_read_attempts`` from the HDF5 library h5py itself loaded (h5py does not wrap it)."""
    here = os.path.dirname(h5py.__file__)
    for pattern in ("../h5py.libs/libhdf5-*.so*", "../h5py/.dylibs/libhdf5*.dylib", ".dylibs/libhdf5*.dylib"):
        for lib in sorted(glob.glob(os.path.join(here, pattern))):
            if "_hl" in os.path.basename(lib):
                continue
            try:
                fn = ctypes.CDLL(lib).H5Pset_metadata_read_attempts
            except (OSError, AttributeError):
                continue
            fn.argtypes, fn.restype = [ctypes.c_int64, ctypes.c_uint], ctypes.c_int
            return fn
    return None


_set_read_attempts = _find_set_read_attempts()


def _open_swmr(path: Path) -> h5py.File:
    """``h5py.File(path, "r", libver="latest", swmr=True)`` with a bounded number of metadata read retries."""
    if _set_read_attempts is None:
        return h5py.File(path, "r", libver="latest", swmr=True)
    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_libver_bounds(h5py.h5f.LIBVER_LATEST, h5py.h5f.LIBVER_LATEST)
    _set_read_attempts(fapl.id, SWMR_READ_ATTEMPTS)
    fid = h5py.h5f.open(os.fsencode(path), h5py.h5f.ACC_RDONLY | h5py.h5f.ACC_SWMR_READ, fapl=fapl)
    return h5py.File(fid)


def _open_session(path: Path) -> h5py.File:
    closed = check_session_file(path)
    try:
        f = _open_swmr(path)
    except (OSError, RuntimeError) as exc:
        if "not already open for SWMR writing" in str(exc):
            raise SessionFileError(f"{path}: the run was killed before it started recording (no data)") from None
        raise SessionFileError(f"{path}: not a readable session ({str(exc)[:120]})") from None
    missing = [g for g in SESSION_GROUPS if g not in f]
    if missing:
        f.close()
        raise SessionFileError(f"{path}: not a beambench session (no /{missing[0]} in the file)")
    try:  # kinds, dtypes, shapes, times, text: one line naming the HDF5 path, before anything is read
        check_schema(f, path.stat().st_size, closed)
    except SessionSchemaError as exc:
        f.close()
        raise SessionFileError(f"{path}: {exc}") from None
    except (OSError, RuntimeError, KeyError, ValueError, TypeError) as exc:
        f.close()
        why = str(exc).strip("'\"")[:120]
        raise SessionFileError(f"{path}: damaged or not a beambench session ({type(exc).__name__}: {why})") from None
    return f


@dataclass
class StreamData:
    """One stream of a session: times and columns as numpy arrays, with its spec."""

    spec: StreamSpec
    host_time_ns: np.ndarray
    device_time: np.ndarray
    columns: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.host_time_ns)


@dataclass
class SessionFile:
    """A session read back: streams, steps, events and general metadata."""

    path: Path
    streams: dict[str, StreamData]
    steps: pd.DataFrame
    events: pd.DataFrame
    general: dict[str, Any]
    attrs: dict[str, Any] = field(default_factory=dict)

    @property
    def protocol_text(self) -> str:
        return str(self.general.get("protocol", ""))

    @property
    def warnings(self) -> list[str]:
        """Every warning the run gave (``/general/warnings``), e.g. a model that cannot stand for the robot."""
        return session_warnings(self.general)

    def to_pandas(self, stream: str) -> pd.DataFrame:
        """One stream as a DataFrame with named columns (``foot_x``, ``lc0``, ``axis_state`` …), ``step`` and
        units in ``df.attrs["units"]`` (:func:`beambench.sinks.session_file.frames.stream_frame`)."""
        from beambench.sinks.session_file.frames import stream_frame

        return stream_frame(self, stream)

    def to_xarray(self) -> xr.Dataset:
        """The session as one xarray Dataset (dimensions time, marker, axis; attributes from ``/general``;
        :func:`beambench.sinks.session_file.frames.session_dataset`)."""
        from beambench.sinks.session_file.frames import session_dataset

        return session_dataset(self)


def session_warnings(general: dict[str, Any]) -> list[str]:
    """The run's warnings stored in ``/general/warnings`` (a JSON list of sentences); none in older sessions."""
    stored = general.get("warnings")
    if isinstance(stored, str):
        stored = [stored]
    return [str(w) for w in stored] if isinstance(stored, list) else []


ENDING_KINDS = ("stop", "interrupted", "fault", "failed", "error")  # the runner's closing event, one per run


def run_ending(events: pd.DataFrame | None) -> tuple[str, str] | None:
    """The run's closing event (kind, message) from ``/events``; None where there is none (a killed run)."""
    if events is None or not len(events) or "kind" not in events:
        return None
    closing = events[events["kind"].astype(str).isin(ENDING_KINDS)]
    if not len(closing):
        return None
    last = closing.iloc[-1]
    return str(last["kind"]), str(last.get("message", ""))


def _read_general(g: h5py.Group) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, item in g.items():
        if isinstance(item, h5py.Group):
            out[key] = _read_general(item)
        else:
            raw = item[()]
            text = raw.decode() if isinstance(raw, bytes) else str(raw)
            out[key] = json.loads(text) if item.attrs.get("encoding") == "json" else text
    return out


# the plotted columns of sessions written before a column said so itself (their standard streams' own)
_PLOTTED_BEFORE = frozenset(
    (spec.name, key)
    for spec in (loadcell_spec(), motor_spec(), track_spec(1.0))
    for key, c in spec.columns.items()
    if c.plotted
)


def _read_stream(name: str, g: h5py.Group, geometry: dict[str, Any] | None = None) -> StreamData:
    # A closed file holds as many rows in every column (the schema check refuses it otherwise); a file still being
    # written (or left open by a killed run) may have grown one dataset of a batch but not yet the next: every
    # column is cut to the rows they all hold.
    cols: dict[str, np.ndarray] = {}
    specs: dict[str, ColumnSpec] = {}
    for key, ds in g.items():
        if key in ("host_time_ns", "device_time"):
            continue
        cols[key] = ds[()]
        labels = tuple(str(x) for x in ds.attrs.get("labels", ()))
        unit, description = str(ds.attrs.get("unit", "")), str(ds.attrs.get("description", ""))
        plotted = bool(ds.attrs["plotted"]) if "plotted" in ds.attrs else (name, key) in _PLOTTED_BEFORE
        specs[key] = ColumnSpec(ds.shape[1:], ds.dtype.str, unit, labels, description, plotted)
    host = g["host_time_ns"][()]
    dev = g["device_time"][()]
    n = min([len(host), len(dev), *(len(c) for c in cols.values())])
    frame = None
    if "up_axis" in g.attrs:
        frame = Frame(
            str(g.attrs["up_axis"]), str(g.attrs.get("forward_axis", "x")), str(g.attrs.get("frame_unit", "m"))
        )
    elif name == "mocap" and geometry:  # sessions written before the frame was part of the stream's description
        frame = Frame(str(geometry.get("up_axis", "z")), str(geometry.get("forward_axis", "x")))
    unit = str(g["device_time"].attrs.get("unit", "s"))
    spec = StreamSpec(name, float(g.attrs.get("rate_hz", 0.0)), specs, unit, frame=frame)
    keep = real_rows(host[:n])
    return StreamData(spec, host[:n][keep], dev[:n][keep], {k: v[:n][keep] for k, v in cols.items()})


def real_rows(host_time_ns: np.ndarray) -> np.ndarray:
    """Which rows hold data: every sample has a host time, so ``host_time_ns == 0`` is a row the file extended
    but never received (a full disk, a killed run: HDF5 fills unwritten rows with zeros). The one exception is
    a first row at 0 followed by real rows: the sim clock starts at 0."""
    keep = host_time_ns != 0
    if len(keep) > 1 and not keep[0] and keep[1:].any():
        keep[0] = True
    return keep


def read_session(path: str | Path) -> SessionFile:
    """Read a session (opened with ``swmr=True``, so files being written or cut off by a kill also read)."""
    import pandas as pd

    path = Path(path)
    with _open_session(path) as f:
        try:
            general = _read_general(f["general"])
            geometry = general.get("geometry") if isinstance(general.get("geometry"), dict) else None
            streams = {name: _read_stream(name, g, geometry) for name, g in f["acquisition"].items()}
            step_rows, event_rows = f["steps"][()], f["events"][()]
            # rows the file extended but never received (see real_rows): a step always has a status, an event a kind
            steps = pd.DataFrame(step_rows[step_rows["status"] != b""])
            for c in ("status", "direction", "kind"):
                if len(steps) and c in steps:
                    steps[c] = steps[c].str.decode("utf-8")
            events = pd.DataFrame(event_rows[event_rows["kind"] != b""])
            for c in ("kind", "message"):
                if len(events):
                    events[c] = events[c].str.decode("utf-8")
            attrs = dict(f.attrs)
        except (OSError, RuntimeError, KeyError, ValueError, TypeError, AttributeError) as exc:
            if isinstance(exc, SessionFileError):
                raise
            why = str(exc).strip("'\"")[:120]
            raise SessionFileError(
                f"{path}: damaged or not a beambench session ({type(exc).__name__}: {why})"
            ) from None
    return SessionFile(path, streams, steps, events, general, attrs)


def read_processing(path: str | Path, name: str) -> pd.DataFrame:
    """Read ``/processing/<name>`` back as a DataFrame, its columns in the order they were written (``steps``:
    one row per protocol step, as ``beambench analyze`` wrote it)."""
    import pandas as pd

    with _open_session(Path(path)) as f:
        g = f["processing"][name]
        stored = json.loads(g.attrs["columns"]) if "columns" in g.attrs else []
        order = [k for k in stored if k in g] + [k for k in g if k not in stored]
        data = {}
        for key in order:
            ds = g[key]
            v = ds[()]
            if ds.dtype.kind in "OS":  # text: variable-length (older sessions) or fixed-length UTF-8 bytes
                v = np.array([x.decode("utf-8") if isinstance(x, bytes) else x for x in v])
            data[key] = v
    lengths = {key: len(v) if np.ndim(v) else 1 for key, v in data.items()}
    if len(set(lengths.values())) > 1:  # a table holds one value per row in every column
        (k0, n0), (k1, n1) = min(lengths.items(), key=lambda kv: kv[1]), max(lengths.items(), key=lambda kv: kv[1])
        raise SessionFileError(f"{path}: /processing/{name}/{k0}: {n0} rows, but {k1} has {n1}: not a table")
    return pd.DataFrame(data)
