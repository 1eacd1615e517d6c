"""The notebook API on a real session made by a short sim run: SessionFile.to_pandas / to_xarray, resample_session
keeping discrete columns discrete with a step column, /processing read back in stored order."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import beambench
from beambench.acquisition.protocol.schema import parse_protocol
from beambench.analysis import analyze_session, resample_session, write_results
from beambench.sinks.session_file.reader import read_processing, read_session

PROTOCOL = "name: nb\nrig: contact\nsweep: {frequencies: [5, 26]}\nsettle_s: 0.2\nrecord_s: 0.3\nsim: {seed: 3}\n"


@pytest.fixture(scope="module")
def session_file(tmp_path_factory) -> Path:
    from beambench.session.run import run_session

    path = tmp_path_factory.mktemp("nb") / "nb.h5"
    result = run_session(parse_protocol(PROTOCOL), PROTOCOL, "sim", path, rerun_mode="off", show_progress=False)
    assert result.status == "completed"
    return path


def test_the_package_and_its_reading_functions_are_documented():
    from beambench.sinks.session_file import frames as session_frames
    from beambench.sinks.session_file.reader import SessionFile

    assert beambench.__doc__ and "to_pandas" in beambench.__doc__
    for f in (SessionFile.to_pandas, SessionFile.to_xarray, resample_session, read_processing, session_frames):
        assert f.__doc__ and len(f.__doc__) > 40


def test_to_pandas_names_the_columns_and_carries_units_and_steps(session_file):
    s = read_session(session_file)
    mocap = s.to_pandas("mocap")
    assert mocap.columns[:9].tolist() == [f"{m}_{a}" for m in ("stage", "tip", "foot") for a in "xyz"]
    assert {"frame", "foot_occluded", "step", "recording", "device_time"} <= set(mocap.columns)
    assert len(mocap) == len(s.streams["mocap"])
    assert np.array_equal(mocap[["foot_x", "foot_y", "foot_z"]].to_numpy(), s.streams["mocap"].columns["data"][:, 2])
    assert mocap.attrs["units"]["foot_x"] == "m" and mocap.attrs["up_axis"] == "z"
    assert mocap["frame"].dtype == np.int64 and mocap["foot_occluded"].dtype == bool
    # every sample knows its step; the record window starts after the settle time
    assert set(mocap["step"]) <= {-1, 0, 1} and {0, 1} <= set(mocap["step"])
    t_settled = (s.steps["t_settled_ns"].iloc[1] - s.steps["t_start_ns"].iloc[0]) / 1e9
    in_step1 = mocap[mocap.step == 1]
    assert in_step1.index[in_step1.recording].min() >= t_settled - 1e-9
    assert not in_step1.recording.all()
    load = s.to_pandas("loadcell")
    assert load.columns[:4].tolist() == ["lc0", "lc1", "lc2", "lc3"] and load.attrs["units"]["lc0"] == "count"
    motor = s.to_pandas("motor")
    assert motor.attrs["units"]["velocity"] == "turn/s" and motor["axis_state"].dtype == np.int32
    with pytest.raises(KeyError, match="streams: "):
        s.to_pandas("nope")


def test_to_xarray_is_one_dataset_with_time_marker_axis(session_file):
    s = read_session(session_file)
    ds = s.to_xarray()
    assert ds["position"].dims == ("time", "marker", "axis")
    assert ds["marker"].values.tolist() == ["stage", "tip", "foot"] and ds["axis"].values.tolist() == ["x", "y", "z"]
    assert ds["position"].attrs["units"] == "m"
    foot = ds["position"].sel(marker="foot", axis="x").values
    assert np.array_equal(foot, s.streams["mocap"].columns["data"][:, 2, 0])
    assert ds["loadcell_counts"].dims == ("loadcell_time", "channel")
    assert ds["motor_axis_state"].dtype == np.int32
    assert ds.attrs["backend"] == "sim" and ds.attrs["rig"] == "contact" and "sweep:" in ds.attrs["protocol"]
    assert ds["step_frequency_hz"].values.tolist() == [5.0, 26.0]
    one = ds.isel(time=ds["step"].values == 1)
    assert one.sizes["time"] > 0 and float(one["time"].min()) >= float(ds["step_t_start_s"][1]) - 1e-9


def test_resample_keeps_discrete_columns_discrete_and_adds_the_step(session_file):
    s = read_session(session_file)
    df = resample_session(s, rate_hz=500.0)
    stored_states = set(np.unique(s.streams["motor"].columns["axis_state"]).tolist())
    assert len(stored_states) > 1  # idle, then closed loop: interpolation would invent states between them
    assert df["motor/axis_state"].dtype == "Int64"
    assert set(df["motor/axis_state"].dropna().unique().tolist()) <= stored_states
    frames = df["mocap/frame"].dropna()
    assert frames.dtype == "Int64" and frames.is_monotonic_increasing
    assert df["mocap/foot_occluded"].dtype == "boolean"
    assert df["mocap/foot_x"].dtype == np.float64
    assert df["step"].dtype == np.int64 and {0, 1} <= set(df["step"])
    # the step column follows /steps on the host clock
    t0 = min(int(st.host_time_ns.min()) for st in s.streams.values())
    boundary = (s.steps["t_start_ns"].iloc[1] - t0) / 1e9
    assert (df.loc[df.index < boundary - 0.01, "step"] <= 0).all()
    assert (df.loc[(df.index > boundary + 0.01) & (df.step >= 0), "step"] == 1).all()


def test_resample_and_to_pandas_name_columns_alike(session_file):
    """One naming: the resampled frame's columns are ``<stream>/`` + the stream's ``to_pandas`` column names."""
    s = read_session(session_file)
    df = resample_session(s, rate_hz=200.0)
    for stream in s.streams:
        own = s.to_pandas(stream).columns
        resampled = {c.split("/", 1)[1] for c in df.columns if c.startswith(f"{stream}/")}
        derived = {"normal_n", "tangential_n"} if stream == "loadcell" else set()
        assert resampled - derived, stream
        assert resampled - derived <= set(own), (stream, sorted(resampled - derived - set(own)))
    assert {"mocap/stage_x", "mocap/foot_z", "loadcell/lc0", "motor/axis_state"} <= set(df.columns)


def test_processing_steps_come_back_in_stored_column_order(session_file):
    a = analyze_session(read_session(session_file))
    write_results(a)
    steps = read_processing(session_file, "steps")
    assert steps.columns.tolist() == a.table.columns.tolist()
    assert steps.columns.tolist() != sorted(steps.columns)
    assert isinstance(steps, pd.DataFrame) and len(steps) == 2


def test_the_readme_example_plots_one_step(session_file, tmp_path, monkeypatch):
    """The README's notebook example ("Read it in a notebook"), run on the short session (its step 1)."""
    import matplotlib

    matplotlib.use("Agg")
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    section = readme.split("Read it in a notebook", 1)[1]
    code = section.split("```python\n", 1)[1].split("```", 1)[0]
    assert len(code.strip().splitlines()) <= 11
    path = code.split('read_session("', 1)[1].split('"', 1)[0]
    code = code.replace(path, str(session_file)).replace("step == 25", "step == 1").replace("[25]", "[1]")
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README.md", "exec"), {})
    assert (tmp_path / "step25.png").stat().st_size > 10_000


def test_every_name_the_analysis_package_exports_resolves_to_its_home_module():
    """``beambench.analysis`` loads its names on first use; each one it lists is there, and is its module's own."""
    import importlib

    import beambench.analysis as analysis

    assert len(analysis.__all__) >= 18
    for name in analysis.__all__:
        value = getattr(analysis, name)
        assert value.__module__.startswith("beambench.analysis."), name
        assert getattr(importlib.import_module(value.__module__), name) is value and name in dir(analysis)
    with pytest.raises(AttributeError, match="no_such_name"):
        analysis.no_such_name  # noqa: B018
