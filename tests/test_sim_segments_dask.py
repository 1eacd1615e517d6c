"""`beambench run --scheduler`: a segmented contact sweep whose later part is computed on a Dask cluster (a local
one, its worker in another process) gives the session the local threads give: the same cut, the same rows, the
same regime at every step; and the option is refused with one line where it has nothing to compute."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from beambench.analysis.session_analysis import analyze_session
from beambench.cli import app
from beambench.sinks.session_file.reader import read_session

CONTACT = """
name: c
rig: contact
sweep: {frequencies: [30, 32, 34, 36, 38]}
settle_s: 1.0
record_s: 1.0
amplitude_mm: 2.0
limits: {max_frequency_hz: 40, max_current_a: 10}
sim: {model: rod5g, params: physical, noise: false, segments: %d}
"""


def run(tmp_path, name: str, *extra: str, segments: int = 2):
    proto = tmp_path / f"{name}.yaml"
    proto.write_text(CONTACT % segments)
    return CliRunner().invoke(
        app, ["run", str(proto), "--out", str(tmp_path), "--name", name, "--rerun", "off", *extra]
    )


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """The same segmented sweep on local threads and with a Dask scheduler (one worker process)."""
    from distributed import LocalCluster  # here, not at collection: only the worker running these tests loads it

    out = tmp_path_factory.mktemp("dask")
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        local = run(out, "local")
        remote = run(out, "remote", "--scheduler", cluster.scheduler_address)
    assert local.exit_code == 0, local.output
    assert remote.exit_code == 0, remote.output
    return read_session(out / "local.h5"), read_session(out / "remote.h5")


@pytest.mark.slow
def test_the_cluster_gives_the_session_of_local_threads(sessions):
    local, remote = sessions
    seg_l, seg_r = local.general["sim_segments"], remote.general["sim_segments"]
    assert len(seg_l["cut_times_s"]) == 1  # the check took the cut: the later part's rows are in the session
    assert seg_r["cut_times_s"] == seg_l["cut_times_s"] and seg_r["cut_checks"] == seg_l["cut_checks"]
    assert seg_r["worker_cpu_s"][1] > 0.3  # the cluster's worker computed the later part (pre-settle and steps)
    for name, stream in local.streams.items():
        for column, values in stream.columns.items():  # every sample, bit for bit
            np.testing.assert_array_equal(np.asarray(remote.streams[name].columns[column]), np.asarray(values))


@pytest.mark.slow
def test_the_cluster_gives_the_regime_of_every_step(sessions):
    local, remote = (analyze_session(s) for s in sessions)
    labels = [[r.row["regime"] for r in a.steps] for a in (local, remote)]
    fractions = [[r.row["in_contact_fraction"] for r in a.steps] for a in (local, remote)]
    assert len(labels[0]) == 5 and labels[0] == labels[1]
    assert fractions[0] == fractions[1]
    assert min(fractions[0]) > 0.2 and max(fractions[0]) < 1.0  # the foot touches and lifts: a real comparison


@pytest.mark.parametrize(
    ("segments", "address", "says"),
    [
        (1, "tcp://127.0.0.1:8786", "sim.segments: 1"),
        (2, "127.0.0.1:8786", "expected an address such as tcp://HOST:8786"),
    ],
)
def test_a_scheduler_with_nothing_to_compute_or_no_address_is_one_line(tmp_path, segments, address, says):
    res = run(tmp_path, "bad", "--scheduler", address, segments=segments)
    assert res.exit_code == 2, res.output
    assert "--scheduler" in res.output and says in res.output
    assert "Traceback" not in res.output
    assert not (tmp_path / "bad.h5").exists()  # nothing written
