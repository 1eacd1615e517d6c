"""The executor seam on a real Dask cluster: a ``distributed.LocalCluster`` (worker processes, TCP) runs the
same sweep as the local process pool, and the tables are equal bit for bit.

Dask is an optional extra ("cluster"); where it is not installed the test is skipped locally with that reason,
but in CI (``CI`` set) a missing Dask is a failure, not a skip.
"""

from __future__ import annotations

import importlib.util
import os

import pandas as pd
import pytest
from typer.testing import CliRunner

from beambench.cli import app
from beambench.studies.executor import ExecutorError, make_executor
from beambench.studies.sweep.run import SweepSpec, load_sweep, run_sweep

# found, not imported, at collection (importing distributed costs ~0.5 s in every test worker)
if importlib.util.find_spec("distributed") is None:
    if os.environ.get("CI"):  # CI installs it: a missing Dask must fail, not skip
        raise ImportError("distributed is not installed; CI installs the 'cluster' extra")
    pytest.skip("Dask is the optional 'cluster' extra: pip install 'dask[distributed]'", allow_module_level=True)

SPEC = SweepSpec.model_validate(
    {
        "name": "dask",
        "scene": "free_beam",
        "grid": {"twist_deg": [30, 90, 150], "chirality": [1, -1]},
        "frequencies": [10, 25],
        "settle_s": 0.2,
        "record_s": 0.2,
    }
)


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        yield c


def test_dask_local_cluster_equals_local_pool(tmp_path, cluster):
    local = run_sweep(SPEC, tmp_path / "local.parquet", workers=2)
    remote = run_sweep(SPEC, tmp_path / "dask.parquet", scheduler=cluster.scheduler_address, batch_size=3)
    assert remote.tasks == 4  # 12 points in tasks of 3, spread over the cluster's two worker processes
    assert len(cluster.scheduler_info["workers"]) == 2
    assert local.computed == remote.computed == 12
    pd.testing.assert_frame_equal(local.table, remote.table, check_exact=True)


def test_sweep_command_with_scheduler(tmp_path, cluster):
    f = tmp_path / "s.yaml"
    f.write_text("name: s\ngrid: {twist_deg: [45, 135]}\nfrequencies: [15]\nsettle_s: 0.2\nrecord_s: 0.2\n")
    out = tmp_path / "s.parquet"
    res = CliRunner().invoke(
        app, ["sweep", str(f), "--out", str(out), "--scheduler", cluster.scheduler_address, "--no-figure"]
    )
    assert res.exit_code == 0, res.output
    assert "2 computed" in res.output
    local = run_sweep(load_sweep(f), tmp_path / "l.parquet", workers=1)
    pd.testing.assert_frame_equal(pd.read_parquet(out), local.table, check_exact=True)


def test_unreachable_scheduler_is_one_clear_error():
    with (
        pytest.raises(ExecutorError, match="cannot connect"),
        make_executor(scheduler="tcp://127.0.0.1:9", connect_timeout_s=1.0),
    ):
        pass
    with pytest.raises(ExecutorError, match="expected an address"), make_executor(scheduler="localhost:8786"):
        pass
