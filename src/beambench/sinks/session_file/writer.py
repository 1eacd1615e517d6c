"""The HDF5 session file's writer: written in SWMR mode and flushed after every poll round of batches (~10 per
second), so a killed run stays readable; the reader is :mod:`beambench.sinks.session_file.reader`.

Layout (NWB-like; ``schema_version`` on the root)::

    /acquisition/<stream>/<column>      time-first, resizable, chunked ~1 s, ``unit`` (+ ``labels``) attributes
    /acquisition/<stream>/host_time_ns  host monotonic receive time (int64 ns)
    /acquisition/<stream>/device_time   the device's own clock (float64 s)
    /steps        one row per protocol step (written when the step starts, updated when it ends)
    /events       time-stamped (host_time_ns, kind, message) rows
    /general      protocol YAML text, calibration, versions, git SHA, backend, device identity, host
    /processing   analysis results written back after the run

Every dataset exists before SWMR mode starts (HDF5 allows no new objects after that); a reader opens with
``swmr=True`` and sees every batch up to the writer's last flush.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

from beambench.acquisition.batch import Batch, StepRecord, StreamSpec
from beambench.common.unfinished import leave_unfinished
from beambench.sinks.session_file.reader import (
    SessionFileError,
)

if TYPE_CHECKING:  # a table handed in is one already: writing a session never loads pandas
    import pandas as pd

SCHEMA_VERSION = "1.0"
EVENT_TEXT = 240  # bytes of a fixed-length event message (SWMR datasets cannot hold variable-length strings)

STEP_DTYPE = np.dtype(
    [
        ("index", "<i4"),
        ("frequency_hz", "<f8"),
        ("t_start_ns", "<i8"),
        ("t_settled_ns", "<i8"),
        ("t_end_ns", "<i8"),
        ("status", "S16"),
        ("direction", "S8"),  # up/down; sessions written before these three columns read as up, sweep, 0
        ("kind", "S12"),
        ("repeat", "<i4"),
    ]
)
EVENT_DTYPE = np.dtype([("host_time_ns", "<i8"), ("kind", "S32"), ("message", f"S{EVENT_TEXT}")])


def _step_row(record: StepRecord) -> np.ndarray:
    """``record`` as one row of the ``/steps`` table."""
    r = record
    return np.array(
        [
            (
                r.index,
                r.frequency_hz,
                r.t_start_ns,
                r.t_settled_ns,
                r.t_end_ns,
                r.status.encode(),
                r.direction.encode(),
                r.kind.encode(),
                r.repeat,
            )
        ],
        dtype=STEP_DTYPE,
    )


def _encode(text: str, size: int) -> bytes:
    data = text.encode("utf-8")
    if len(data) <= size:
        return data
    return data[: size - 3].decode("utf-8", "ignore").encode() + b"..."


class SessionWriteError(OSError):
    """The session file could not take a write (a full disk, an I/O error): one line, no HDF5 stack."""


SPACE_RESERVE_BYTES = 4 * 1024 * 1024  # held beside the session; freed on a full disk so the file can close whole


def _reason(exc: BaseException) -> str:
    """The OS reason inside an HDF5 error (``No space left on device``), else its first line."""
    text = str(exc)
    found = re.search(r"error message = '([^']+)'", text)
    if found:
        return found.group(1)
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return (text.splitlines() or [type(exc).__name__])[0][:160]


class _SpaceReserve:
    """Disk space held for the closing writes: a file of ``nbytes`` preallocated in ``folder`` and unlinked at once
    (so it goes with the process, whatever ends it). :meth:`release` frees it when the disk is full."""

    def __init__(self, folder: Path, nbytes: int | None = None) -> None:
        nbytes = SPACE_RESERVE_BYTES if nbytes is None else nbytes
        self.nbytes = nbytes
        name = folder / f".beambench-reserve-{os.getpid()}-{id(self):x}"
        fd = os.open(name, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o600)
        os.unlink(name)
        try:
            if hasattr(os, "posix_fallocate"):
                os.posix_fallocate(fd, 0, nbytes)
            else:  # pragma: no cover - macOS: write it out
                os.write(fd, bytes(nbytes))
        except OSError:
            os.close(fd)
            raise
        self.fd: int | None = fd

    def release(self) -> bool:
        """Free the reserve; True if there was one to free."""
        if self.fd is None:
            return False
        with contextlib.suppress(OSError):
            os.ftruncate(self.fd, 0)
        os.close(self.fd)
        self.fd = None
        return True


_WRITE_FAILURES = (OSError, RuntimeError, ValueError, KeyError)  # how one write of h5py's fails (a full disk …)


class SessionWriter:
    """A :class:`~beambench.acquisition.hub.Sink` that writes one session file (the run's critical sink).

    Every h5py object of the file is created, used and closed by the thread that calls the sink (the runner's),
    and is referenced only from here: a failing write raises a :class:`SessionWriteError` that carries no HDF5
    traceback (whose frames would keep h5py ids alive for the garbage collector to free later, from any thread).

    On the first failed write (a full disk) the writer stops taking batches, frees its space reserve and keeps
    only the closing records (step status, the last events), so the file closes whole with only real rows; a
    second failure ends all writing, and :meth:`close` then releases the file without flushing.
    """

    def __init__(self, path: str | Path, general: dict[str, Any]) -> None:
        self.path = Path(path)
        self.label = f"session file {self.path}"
        self.general = general
        self._f: h5py.File | None = None
        self._datasets: dict[str, list[tuple[str, _Appender]]] = {}
        self._tables: dict[str, _Appender] = {}
        self._dirty = False
        self._reserve: _SpaceReserve | None = None
        self.failed: str | None = None  # the first failure's reason
        self._dead = False  # a second failure: nothing more is written
        self._step_rows: dict[int, np.ndarray] = {}  # every step's latest row, rewritten at a close after a failure

    # --- Sink -------------------------------------------------------------------------------------------
    def open(self, specs: list[StreamSpec]) -> None:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SessionFileError(
                f"{self.path.parent}: cannot create the output folder ({exc.strerror or exc})"
            ) from None
        try:
            self._reserve = _SpaceReserve(self.path.parent)
        except OSError as exc:
            if exc.errno not in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
                raise SessionFileError(f"{self.path}: cannot create the session file ({exc.strerror or exc})") from None
            free = shutil.disk_usage(self.path.parent).free if self.path.parent.exists() else 0
            raise SessionFileError(
                f"{self.path.parent}: not enough free space for a run ({exc.strerror or exc}; {free / 1e6:.1f} MB "
                f"free, the session keeps {SPACE_RESERVE_BYTES / 1e6:.0f} MB in reserve for its closing writes)"
            ) from None
        try:
            self._create(specs)
        except BaseException:
            self._reserve.release()
            raise

    def _create(self, specs: list[StreamSpec]) -> None:
        f = create_session_file(self.path, chunk_cache_bytes(specs))
        try:
            f.attrs["schema_version"] = SCHEMA_VERSION
            f.attrs["software"] = "beambench"
            _write_general(f.create_group("general"), self.general)
            acq = f.create_group("acquisition")
            for spec in specs:
                _create_stream(acq.create_group(spec.name), spec)
            f.create_dataset("steps", shape=(0,), maxshape=(None,), dtype=STEP_DTYPE, chunks=(64,))
            f.create_dataset("events", shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE, chunks=(64,))
            f.create_group("processing")
            self._datasets = {name: [(k, _Appender(ds)) for k, ds in g.items()] for name, g in acq.items()}
            self._tables = {name: _Appender(f[name]) for name in ("steps", "events")}  # held: no ids freed per write
            f.swmr_mode = True
            f.flush()
        except (OSError, RuntimeError, ValueError) as exc:
            why = _reason(exc)
        else:
            self._f = f
            return
        self._datasets, self._tables = {}, {}
        try:
            f.close()
        except (OSError, RuntimeError, ValueError):
            leave_unfinished(self.label, f)  # HDF5's exit handler would retry the close and crash
        del f
        raise SessionFileError(f"{self.path}: cannot write the session file ({why})")

    def write(self, batch: Batch) -> None:
        if self.failed is not None:
            return  # the data stream stopped at the first failure
        self._guard(self._write, batch)

    def _write(self, batch: Batch) -> None:
        for name, appender in self._datasets[batch.stream]:
            if name == "host_time_ns":
                appender.append(batch.host_time_ns)
            elif name == "device_time":
                appender.append(batch.device_time)
            else:
                appender.append(batch.columns[name])
        self._dirty = True

    def flush(self) -> None:
        """Make every batch written so far visible to SWMR readers (called once per poll round)."""
        if self._dirty and self.failed is None:
            self._guard(self._flush)
            self._dirty = False

    def event(self, host_time_ns: int, kind: str, message: str) -> None:
        row = np.array([(host_time_ns, _encode(kind, 32), _encode(message, EVENT_TEXT))], dtype=EVENT_DTYPE)
        self._guard(self._event, row, record=True)

    def _event(self, row: np.ndarray) -> None:
        self._tables["events"].append(row)
        self._flush()

    def step(self, record: StepRecord) -> None:
        self._guard(self._step, record, record=True)

    def _step(self, record: StepRecord) -> None:
        steps = self._tables["steps"]
        row = _step_row(record)
        self._step_rows[record.index] = row
        if record.index < steps.n:
            steps.overwrite(record.index, row)
        else:
            steps.append(row)
        self._flush()

    def _rewrite_steps(self) -> None:
        """After a failed write: the whole /steps table again from memory, in the freed reserve. A flush that
        failed may have kept a row's extent but not its data, which the rollback cannot see (a soak found a
        session closed after a full disk with no step row at all)."""
        if sorted(self._step_rows) != list(range(len(self._step_rows))):  # none, or not the run's own 0, 1, …
            return
        steps = self._tables["steps"]
        rows = np.concatenate([self._step_rows[i] for i in sorted(self._step_rows)])
        if steps.n < len(rows):
            steps.dsid.set_extent((len(rows), *steps.row_shape))
            steps.n = len(rows)
        steps.overwrite(0, rows)

    def close(self) -> None:
        """Flush and close the file, releasing every h5py object here, in the writer's thread.

        A file that cannot be flushed (the disk stayed full) is not closed: HDF5 would retry the flush on every
        id it releases, fail on each (h5py prints "Can't decrement id ref count" for each) and crash at exit.
        Its objects are kept and the file stays as of its last flush, which SWMR readers read; the command line
        then ends the process without HDF5's exit handler (:mod:`beambench.common.unfinished`)."""
        f, self._f = self._f, None
        if f is None:
            return
        why = None
        if self.failed is not None and not self._dead:
            with contextlib.suppress(OSError, RuntimeError, ValueError, KeyError):
                self._rewrite_steps()
        if not self._dead:
            try:
                f.flush()
            except MemoryError:  # HDF5 could not allocate: as a full disk (its exit handler would corrupt the heap)
                why = "out of memory"
            except (OSError, RuntimeError, ValueError) as exc:
                why = _reason(exc)
        if self._dead or why is not None:
            leave_unfinished(self.label, f, self._datasets, self._tables)
        else:
            self._datasets, self._tables = {}, {}
            try:
                f.close()
            except MemoryError:
                why = "out of memory"
            except (OSError, RuntimeError, ValueError) as exc:
                why = _reason(exc)
        del f
        if self._reserve is not None:
            self._reserve.release()
        if why is not None and not self._dead:
            self._dead = True
            raise SessionWriteError(f"cannot close ({why})")

    def _appenders(self) -> list[_Appender]:
        return [a for cols in self._datasets.values() for _, a in cols] + list(self._tables.values())

    def _flush(self) -> None:
        self._file.flush()
        for appender in self._appenders():
            appender.flushed = appender.n

    def _guard(self, op: Callable[..., None], *args: Any, record: bool = False) -> None:
        """Run one write; a failure becomes one :class:`SessionWriteError` raised outside the HDF5 frames.

        The first failure frees the reserve and rolls back to the last flush; a ``record`` (a step row or an
        event, not data) whose write failed is then written again, in the reserve, before the error is raised:
        a step's row and its ``step`` event are both in the file or neither, whichever of them met the full disk."""
        if self._dead:
            return
        try:
            op(*args)
            return
        except _WRITE_FAILURES as exc:
            why = _reason(exc)
        if self.failed is None:
            self.failed = why
            freed = self._reserve is not None and self._reserve.release() and self._roll_back()
            if freed and (not record or self._again(op, *args)):
                raise SessionWriteError(why)  # the closing records may still fit in the freed reserve
        self._dead = True
        raise SessionWriteError(why)

    @staticmethod
    def _again(op: Callable[..., None], *args: Any) -> bool:
        """``op`` once more (after the rollback, in the freed reserve); False if it failed again."""
        try:
            op(*args)
        except _WRITE_FAILURES:
            return False
        return True

    def _roll_back(self) -> bool:
        """Every dataset back to its rows of the last successful flush; False if even that failed."""
        try:
            for appender in self._appenders():
                appender.rollback()
        except (OSError, RuntimeError, ValueError):
            return False
        return True

    @property
    def _file(self) -> h5py.File:
        if self._f is None:
            raise RuntimeError("session file is not open")
        return self._f


def _create_stream(g: h5py.Group, spec: StreamSpec) -> None:
    g.attrs["rate_hz"] = spec.rate_hz
    g.attrs["description"] = spec.description
    if spec.frame is not None:
        g.attrs["up_axis"] = spec.frame.up_axis
        g.attrs["forward_axis"] = spec.frame.forward_axis
        g.attrs["frame_unit"] = spec.frame.unit
    chunk = chunk_rows(spec)
    ht = g.create_dataset("host_time_ns", shape=(0,), maxshape=(None,), dtype="<i8", chunks=(chunk,))
    ht.attrs["unit"] = "ns"
    dt = g.create_dataset("device_time", shape=(0,), maxshape=(None,), dtype="<f8", chunks=(chunk,))
    dt.attrs["unit"] = spec.device_time_unit
    for name, col in spec.columns.items():
        ds = g.create_dataset(
            name, shape=(0, *col.shape), maxshape=(None, *col.shape), dtype=col.dtype, chunks=(chunk, *col.shape)
        )
        ds.attrs["unit"] = col.unit
        ds.attrs["description"] = col.description
        if col.labels:
            ds.attrs["labels"] = list(col.labels)
        ds.attrs["plotted"] = col.plotted


class _Appender:
    """Appends rows to one time-first dataset through the low-level API (~3x faster than ``ds[n:] = v``)."""

    __slots__ = ("dsid", "dtype", "flushed", "n", "row_shape")

    def __init__(self, ds: h5py.Dataset) -> None:
        self.dsid, self.dtype, self.row_shape, self.n = ds.id, ds.dtype, ds.shape[1:], ds.shape[0]
        self.flushed = self.n  # rows known on disk (at the writer's last successful flush)

    def rollback(self) -> None:
        """Forget the rows appended since the last successful flush (a failed flush may have lost their data
        but not the dataset's new extent: rows of zeros); the next rows go where they began."""
        if self.n > self.flushed:
            self.dsid.set_extent((self.flushed, *self.row_shape))
            self.n = self.flushed

    def append(self, values: np.ndarray) -> None:
        arr = np.ascontiguousarray(values, dtype=self.dtype)
        if arr.shape[1:] != self.row_shape:
            raise ValueError(f"rows of shape {arr.shape[1:]}, expected {self.row_shape}")
        m = len(arr)
        if m == 0:
            return
        self.dsid.set_extent((self.n + m, *self.row_shape))
        try:
            file_space = self.dsid.get_space()
            file_space.select_hyperslab((self.n,) + (0,) * len(self.row_shape), arr.shape)
            self.dsid.write(h5py.h5s.create_simple(arr.shape), file_space, arr)
        except BaseException:
            with contextlib.suppress(Exception):  # no rows of zeros where the write failed
                self.dsid.set_extent((self.n, *self.row_shape))
            raise
        self.n += m

    def overwrite(self, index: int, rows: np.ndarray) -> None:
        """Write ``rows`` over the rows from ``index`` on (they exist)."""
        arr = np.ascontiguousarray(rows, dtype=self.dtype)
        file_space = self.dsid.get_space()
        file_space.select_hyperslab((index,) + (0,) * len(self.row_shape), arr.shape)
        self.dsid.write(h5py.h5s.create_simple(arr.shape), file_space, arr)


def _append(ds: h5py.Dataset, values: np.ndarray) -> None:
    _Appender(ds).append(values)


def _write_general(g: h5py.Group, general: dict[str, Any]) -> None:
    for key, value in general.items():
        if isinstance(value, dict):
            _write_general(g.create_group(key), value)
        elif isinstance(value, str):
            g.create_dataset(key, data=value, dtype=h5py.string_dtype())
        else:
            g.create_dataset(key, data=json.dumps(value), dtype=h5py.string_dtype())
            g[key].attrs["encoding"] = "json"


def chunk_rows(spec: StreamSpec) -> int:
    """Rows per HDF5 chunk of a stream: about one second of samples."""
    return max(16, int(spec.rate_hz))


MIN_CHUNK_CACHE_BYTES = 64 * 1024


def chunk_cache_bytes(specs: list[StreamSpec]) -> int:
    """The writer's chunk cache per dataset: two of the largest chunk, at least 64 KiB. Rows are appended once
    and never read back, so one chunk being filled is all a cache needs to hold; HDF5's default (1 MiB per
    dataset) grew the writer's memory without end (+45 MB per 10 min of soak data; flat at 64 KiB) and made
    appends ~4x slower."""
    largest = 0
    for spec in specs:
        for col in spec.columns.values():
            row = int(np.prod(col.shape, dtype=np.int64)) * np.dtype(col.dtype).itemsize
            largest = max(largest, chunk_rows(spec) * max(row, 8))
    return max(MIN_CHUNK_CACHE_BYTES, 2 * largest)


def create_session_file(path: Path, chunk_cache: int = MIN_CHUNK_CACHE_BYTES) -> h5py.File:
    """A new, empty HDF5 file at ``path``, created exclusively: an existing file is never overwritten."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SessionFileError(f"{path.parent}: cannot create the output folder ({exc.strerror or exc})") from None
    try:
        # "x": fail if it exists (O_EXCL); a small chunk cache (see chunk_cache_bytes)
        return h5py.File(path, "x", libver="latest", rdcc_nbytes=chunk_cache)
    except FileExistsError:
        raise SessionFileError(f"{path}: a file of that name exists; sessions are never overwritten") from None
    except OSError as exc:
        if path.exists():  # h5py reports EEXIST in words on some builds
            raise SessionFileError(f"{path}: a file of that name exists; sessions are never overwritten") from None
        raise SessionFileError(f"{path}: cannot create the session file ({exc.strerror or exc})") from None


# --- reading ---------------------------------------------------------------------------------------------
def append_general(path: str | Path, extra: dict[str, Any]) -> None:
    """Add entries to ``/general`` of a closed session (things known only after the run, e.g. ECHO tables)."""
    with h5py.File(path, "r+") as f:
        g = f["general"]
        for key, value in extra.items():
            if key in g:
                del g[key]
            _write_general(g, {key: value})


def write_processing(path: str | Path, name: str, table: pd.DataFrame | dict[str, np.ndarray]) -> None:
    """Write analysis results to ``/processing/<name>`` (one dataset per column), replacing any old copy.

    HDF5 does not reuse the space of a deleted object, so deleting and re-creating the group grew the session
    by ~9 kB per ``analyze``. A table of the same columns, shapes and types (the same session analysed again) is
    written over the old one in place instead: the file does not grow. A table of another layout still replaces
    the group; ``h5repack SESSION.h5 COPY.h5`` reclaims the space that leaves (README, "Session files")."""
    cols = dict(table) if isinstance(table, dict) else {c: table[c].to_numpy() for c in table.columns}
    arrays = {key: _stored(values) for key, values in cols.items()}
    with h5py.File(path, "r+") as f:
        proc = f.require_group("processing")
        old = proc.get(name)
        if isinstance(old, h5py.Group) and _same_layout(old, arrays):
            for key, arr in arrays.items():
                old[key][...] = arr
            return
        if name in proc:
            del proc[name]
        g = proc.create_group(name)
        g.attrs["columns"] = json.dumps(list(cols))  # HDF5 lists a group's members by name: keep the order
        for key, arr in arrays.items():
            g.create_dataset(key, data=arr)


def _stored(values: Any) -> np.ndarray:
    """A column as stored: text as fixed-length UTF-8 bytes (rewritten in place without new heap space)."""
    arr = np.asarray(values)
    if arr.dtype.kind in "OUS":
        encoded = [str(x).encode("utf-8") for x in arr.reshape(-1)]
        width = max([len(b) for b in encoded] + [1])
        return np.array(encoded, dtype=f"S{width}").reshape(arr.shape)
    return arr


def _same_layout(group: h5py.Group, arrays: dict[str, np.ndarray]) -> bool:
    if set(group.keys()) != set(arrays):
        return False
    for key, arr in arrays.items():
        ds = group[key]
        if not isinstance(ds, h5py.Dataset) or ds.shape != arr.shape:
            return False
        if arr.dtype.kind == "S":
            if ds.dtype.kind != "S" or ds.dtype.itemsize < arr.dtype.itemsize:
                return False
        elif ds.dtype != arr.dtype:
            return False
    return True
