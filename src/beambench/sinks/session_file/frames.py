"""A session read back as labelled tables for notebooks: one stream as a pandas DataFrame, the whole session as
one xarray Dataset (:meth:`SessionFile.to_pandas`, :meth:`SessionFile.to_xarray` call these).

Both are views of the raw data as recorded (no clock fits, no calibration, occluded markers keep their stored
values; :func:`beambench.analysis.resample_session` puts every stream on one clock-corrected timeline). Time is
the host receive time in seconds from the session's start (:func:`session_t0_ns`); every sample carries the index
of the protocol step it falls in (``step``, -1 between steps) and whether it lies in that step's record window
(``recording``, after the settle time).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import pandas as pd

from beambench.acquisition.batch import StreamSpec

if TYPE_CHECKING:
    import xarray as xr


class StreamLike(Protocol):
    """What the frames read of a stream (a :class:`beambench.sinks.session_file.reader.StreamData`)."""

    @property
    def spec(self) -> StreamSpec: ...

    @property
    def host_time_ns(self) -> np.ndarray: ...

    @property
    def device_time(self) -> np.ndarray: ...

    @property
    def columns(self) -> dict[str, np.ndarray]: ...

    def __len__(self) -> int: ...


class SessionLike(Protocol):
    """What the frames read of a session (a :class:`beambench.sinks.session_file.reader.SessionFile`; typed structurally, so
    the reader, whose ``to_pandas``/``to_xarray`` call these, is not imported back)."""

    @property
    def path(self) -> Path: ...

    @property
    def streams(self) -> Mapping[str, StreamLike]: ...

    @property
    def steps(self) -> pd.DataFrame: ...

    @property
    def general(self) -> dict[str, Any]: ...

    @property
    def attrs(self) -> dict[str, Any]: ...


NS = 1e9
AXES = ("x", "y", "z")
MOCAP = "mocap"
# The xarray names of the standard streams' array columns; other columns are ``<stream>_<column>``.
_VARIABLE = {(MOCAP, "data"): "position", (MOCAP, "frame"): "frame", (MOCAP, "occluded"): "occluded"}
_VARIABLE[("loadcell", "data")] = "loadcell_counts"


def session_t0_ns(session: SessionLike) -> int:
    """The session's time origin on the host clock (ns): the start of its first step, else its first sample."""
    if len(session.steps):
        return int(session.steps["t_start_ns"].min())
    firsts = [int(s.host_time_ns[0]) for s in session.streams.values() if len(s)]
    return min(firsts) if firsts else 0


def step_of(session: SessionLike, host_time_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For host times (ns): the index of the step each falls in (-1 outside every step) and whether it lies in
    that step's record window (``t_settled_ns <= t < t_end_ns``)."""
    t = np.asarray(host_time_ns, np.int64)
    step = np.full(len(t), -1, np.int64)
    recording = np.zeros(len(t), bool)
    st = session.steps
    if not len(st):
        return step, recording
    rows = zip(*(st[c].to_numpy(np.int64) for c in ("index", "t_start_ns", "t_settled_ns", "t_end_ns")))
    for index, start, settled, end in rows:
        inside = (t >= start) & (t < end)
        step[inside] = index
        recording |= inside & (t >= settled)
    return step, recording


def _stream(session: SessionLike, stream: str) -> StreamLike:
    if stream not in session.streams:
        raise KeyError(f"{stream!r}: no such stream in {session.path} (streams: {', '.join(session.streams)})")
    return session.streams[stream]


def flat_names(stream: str, column: str, shape: tuple[int, ...], labels: tuple[str, ...]) -> list[str]:
    """DataFrame column names of one stored column: ``foot_x`` for mocap positions, ``foot_occluded``, ``lc0``,
    ``frame``; unlabelled array columns get ``<column>_<i>``. The one naming of ``to_pandas`` and (behind the
    stream's name) of :func:`beambench.analysis.resample_session`."""
    if not shape:
        return [column]
    first = list(labels) if len(labels) == shape[0] else [f"{column}_{i}" for i in range(shape[0])]
    if len(shape) == 1:
        if stream == MOCAP and column != "data":
            return [f"{m}_{column}" for m in first]
        return first
    last = AXES if shape[-1] == 3 else tuple(str(i) for i in range(shape[-1]))
    return [f"{m}_{a}" for m in first for a in last]


def stream_frame(session: SessionLike, stream: str) -> pd.DataFrame:
    """One stream as a DataFrame: one row per sample, indexed by ``t_s`` (host receive time, s from
    :func:`session_t0_ns`), with named columns (mocap: ``stage_x`` … ``foot_z``, ``frame``, ``foot_occluded``;
    loadcell: ``lc0`` … ``lc3``, ``seq``; motor: ``position``, ``axis_state`` …) in their stored dtypes, plus
    ``host_time_ns``, ``device_time``, ``step`` and ``recording``.

    ``df.attrs`` holds the metadata pandas has no place for: ``units`` and ``descriptions`` (column → text),
    ``stream``, ``rate_hz`` and, for positions, ``up_axis`` and ``forward_axis``.
    """
    s = _stream(session, stream)
    t0 = session_t0_ns(session)
    data: dict[str, np.ndarray] = {}
    units: dict[str, str] = {"host_time_ns": "ns", "device_time": s.spec.device_time_unit, "step": "", "recording": ""}
    descriptions: dict[str, str] = {
        "host_time_ns": "host monotonic receive time",
        "device_time": "the device's own clock",
        "step": "protocol step index (-1 between steps)",
        "recording": "inside the step's record window (after settling)",
    }
    first = ["data"] if "data" in s.columns else []
    for col in first + [c for c in s.columns if c != "data"]:
        values = np.asarray(s.columns[col])
        spec = s.spec.columns.get(col)
        labels = spec.labels if spec is not None else ()
        names = flat_names(stream, col, values.shape[1:], labels)
        flat = values.reshape(len(values), -1)
        for i, nm in enumerate(names):
            data[nm] = flat[:, i]
            units[nm] = spec.unit if spec is not None else ""
            descriptions[nm] = spec.description if spec is not None else ""
    data["host_time_ns"] = np.asarray(s.host_time_ns, np.int64)
    data["device_time"] = np.asarray(s.device_time, np.float64)
    data["step"], data["recording"] = step_of(session, s.host_time_ns)
    index = pd.Index((data["host_time_ns"] - t0) / NS, name="t_s")
    df = pd.DataFrame(data, index=index)
    df.attrs = {"stream": stream, "rate_hz": s.spec.rate_hz, "units": units, "descriptions": descriptions}
    if s.spec.frame is not None:
        df.attrs.update(up_axis=s.spec.frame.up_axis, forward_axis=s.spec.frame.forward_axis)
    return df


def _time_dim(stream: str) -> str:
    return "time" if stream == MOCAP else f"{stream}_time"


def _dims(stream: str, column: str, ndim: int) -> tuple[str, ...]:
    """The per-sample dimensions of a column: mocap (marker, axis); a labelled channel axis is ``channel``."""
    if stream == MOCAP:
        return ("marker", "axis")[:ndim]
    return tuple("channel" if i == 0 else f"{stream}_{column}_{i}" for i in range(ndim))


def _flat_attrs(general: dict[str, Any], prefix: str = "") -> dict[str, str | int | float]:
    """``/general`` as flat netCDF-safe attributes: nested groups joined with ``/``, other values as JSON."""
    out: dict[str, str | int | float] = {}
    for key, value in general.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flat_attrs(value, f"{name}/"))
        elif isinstance(value, str | int | float) and not isinstance(value, bool):
            out[name] = value
        else:
            out[name] = json.dumps(value, default=str)
    return out


def session_dataset(session: SessionLike) -> xr.Dataset:
    """The whole session as one xarray Dataset.

    Dimensions: ``time`` (mocap samples), ``marker`` and ``axis`` (x, y, z) for ``position`` (m), ``occluded`` and
    ``frame``; every other stream on its own time dimension (``loadcell_time``, ``motor_time``) with variables
    ``<stream>_<column>`` (``loadcell_counts`` over ``channel``, ``motor_velocity`` …); each time dimension has the
    coordinates ``step`` / ``<stream>_step`` and ``recording`` / ``<stream>_recording``; the step table is on the
    ``steps`` dimension (``step_frequency_hz``, ``step_t_start_s`` …). Variables carry ``units`` and
    ``description``; the Dataset's attributes are ``/general`` flattened (``protocol``, ``backend``,
    ``identity/…``), plus ``session_path`` and ``t0_host_time_ns``.
    """
    import xarray as xr

    t0 = session_t0_ns(session)
    variables: dict[str, Any] = {}
    coords: dict[str, Any] = {}
    for name, s in session.streams.items():
        tdim = _time_dim(name)
        pre = "" if name == MOCAP else f"{name}_"
        coords[tdim] = (tdim, (np.asarray(s.host_time_ns, np.int64) - t0) / NS, {"units": "s"})
        step, recording = step_of(session, s.host_time_ns)
        coords[f"{pre}step"] = (tdim, step)
        coords[f"{pre}recording"] = (tdim, recording)
        variables[f"{name}_device_time"] = (tdim, np.asarray(s.device_time), {"units": s.spec.device_time_unit})
        for col, values in s.columns.items():
            arr = np.asarray(values)
            spec = s.spec.columns.get(col)
            dims = (tdim, *_dims(name, col, arr.ndim - 1))
            attrs: dict[str, Any] = {
                "units": spec.unit if spec else "",
                "description": spec.description if spec else "",
            }
            if name == MOCAP and col == "data" and s.spec.frame is not None:
                attrs.update(up_axis=s.spec.frame.up_axis, forward_axis=s.spec.frame.forward_axis)
            variables[_VARIABLE.get((name, col), f"{name}_{col}")] = (dims, arr, attrs)
            if spec is not None and spec.labels and len(spec.labels) == arr.shape[1]:
                coords[dims[1]] = (dims[1], list(spec.labels))
            if arr.ndim == 3 and arr.shape[2] == 3:
                coords[dims[2]] = (dims[2], list(AXES))
    steps = session.steps
    for col in steps.columns:
        values = steps[col].to_numpy()
        if col.endswith("_ns"):
            variables[f"step_{col.removesuffix('_ns')}_s"] = ("steps", (values - t0) / NS, {"units": "s"})
        elif col != "index":
            variables[f"step_{col}"] = ("steps", values.astype(str) if values.dtype == object else values)
    if "index" in steps.columns:
        coords["steps"] = ("steps", steps["index"].to_numpy())
    attrs = _flat_attrs(session.general)
    attrs.update({k: str(v) for k, v in session.attrs.items()})
    attrs.update(session_path=str(session.path), t0_host_time_ns=t0)
    return xr.Dataset(variables, coords=coords, attrs=attrs)
