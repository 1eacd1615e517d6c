"""The HDF5 session store: layout, units, SWMR reading while the writer is open."""

import h5py
import numpy as np
import pytest

from beambench.acquisition.batch import Batch, StepRecord
from beambench.acquisition.hub import Hub
from beambench.acquisition.streams import loadcell_spec, mocap_spec
from beambench.sinks.session_file.reader import read_processing, read_session
from beambench.sinks.session_file.writer import SessionWriter, write_processing


def _batches(n0, n):
    t = np.arange(n0, n0 + n)
    mocap = Batch(
        "mocap",
        (t * 2_777_778).astype(np.int64),
        t / 360.0,
        {"data": np.random.rand(n, 3, 3), "frame": t, "occluded": np.zeros((n, 3), bool)},
    )
    lc = Batch(
        "loadcell",
        (t * 1_000_000).astype(np.int64),
        t / 1000.0,
        {"data": np.full((n, 4), 7, np.int32), "seq": t, "sync_edges": t // 3},
    )
    return mocap, lc


def test_layout_units_and_swmr_reader(tmp_path):
    path = tmp_path / "s.h5"
    w = SessionWriter(path, {"protocol": "name: x\n", "backend": "sim", "identity": {"model": "prb3", "dt": 1e-4}})
    hub = Hub([w], critical=(w,))
    hub.open([mocap_spec(("stage", "tip", "foot")), loadcell_spec()])
    for k in range(3):
        for b in _batches(100 * k, 100):
            hub.write(b)
        hub.flush()
        # a reader sees every flushed batch while the writer is still open
        s = read_session(path)
        assert len(s.streams["mocap"]) == 100 * (k + 1)
        assert len(s.streams["loadcell"]) == 100 * (k + 1)
    hub.step(StepRecord(0, 5.0, 10))
    hub.step(StepRecord(0, 5.0, 10, 20, 30, "done"))
    hub.event(31, "stop", "all steps done")
    hub.close()

    s = read_session(path)
    assert s.general["protocol"] == "name: x\n"
    assert s.general["identity"] == {"model": "prb3", "dt": 1e-4}
    assert list(s.steps["status"]) == ["done"] and s.steps["t_end_ns"][0] == 30
    assert list(s.events["kind"]) == ["stop"]
    assert s.streams["mocap"].spec.columns["data"].labels == ("stage", "tip", "foot")
    assert s.streams["loadcell"].columns["data"].dtype == np.int32
    with h5py.File(path, "r") as f:
        assert f["acquisition/mocap/data"].attrs["unit"] == "m"
        assert f["acquisition/loadcell/host_time_ns"].attrs["unit"] == "ns"
        assert f.attrs["schema_version"] == "1.0"


def test_processing_round_trip(tmp_path):
    path = tmp_path / "s.h5"
    w = SessionWriter(path, {"protocol": ""})
    w.open([loadcell_spec()])
    w.close()
    import pandas as pd

    table = pd.DataFrame({"f": [1.0, 2.0], "regime": ["1", "1/2"]})
    write_processing(path, "steps", table)
    write_processing(path, "steps", table)  # replacing is allowed
    back = read_processing(path, "steps")
    assert list(back["regime"]) == ["1", "1/2"] and back["f"].tolist() == [1.0, 2.0]


def test_long_event_messages_are_truncated_not_fatal(tmp_path):
    path = tmp_path / "s.h5"
    w = SessionWriter(path, {"protocol": "name: x\n"})  # a session always holds its protocol
    w.open([])
    w.event(1, "fault", "x" * 1000)
    w.close()
    msg = read_session(path).events["message"][0]
    assert msg.endswith("...") and len(msg) <= 240


def test_batch_rejects_ragged_columns():
    with pytest.raises(ValueError, match="rows"):
        Batch("x", np.zeros(3, np.int64), np.zeros(3), {"a": np.zeros(2)})
