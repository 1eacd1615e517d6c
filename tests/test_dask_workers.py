"""A Dask cluster of more than five workers is used whole: ``run --scheduler`` spreads a sweep's later segments
over every worker (one scene each while there are enough) and an executor on a scheduler counts every worker's
threads (``Client.scheduler_info()`` lists only the first five workers in some Dask versions)."""

from __future__ import annotations

import pytest

from beambench.acquisition.protocol.schema import parse_protocol
from beambench.backends.remote_scene import remote_scenes
from beambench.backends.sim import build_scene
from beambench.session.slices import sim_slice
from beambench.studies.executor import make_executor

WORKERS = 6  # one more than scheduler_info()'s cut

CONTACT = """
name: c
rig: contact
sweep: {frequencies: [30, 32]}
settle_s: 0.1
record_s: 0.1
sim: {model: rod5g, params: physical, noise: false, segments: 2}
"""


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster  # here, not at collection: only the worker running these tests loads it

    with LocalCluster(n_workers=WORKERS, threads_per_worker=1, processes=False, dashboard_address=None) as local:
        yield local


def test_a_sweeps_scenes_go_one_to_each_worker(cluster):
    from distributed import Client

    with Client(cluster) as client:
        scenes = remote_scenes(client, sim_slice(parse_protocol(CONTACT)), WORKERS, build_scene)
        try:
            holding = {worker: len(keys) for worker, keys in client.has_what().items()}
        finally:
            for scene in scenes:
                scene.close()
    assert len(holding) == WORKERS and set(holding.values()) == {1}, holding  # each worker holds one scene


def test_an_executor_on_a_scheduler_counts_every_workers_threads(cluster):
    with make_executor(scheduler=cluster.scheduler_address) as pool:
        assert pool.workers == WORKERS
        assert sorted(pool.executor.map(abs, range(-3, 3))) == [0, 1, 1, 2, 2, 3]  # and runs work there
