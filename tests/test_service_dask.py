"""The service on an existing Dask cluster (``BRDFFIT_DASK_SCHEDULER``): its jobs run
on the cluster's workers through the batch job's runner, results and plots as on
local workers."""

from __future__ import annotations

import pytest

from brdffit.batch.cluster import local_worker_env
from brdffit.client import Client
from tests.api_fixtures import FAST, Server, table_bytes, write

pytestmark = pytest.mark.system


def test_jobs_run_on_the_dask_cluster(tmp_path):
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0", env=local_worker_env(1)) as cluster:
        env = {"BRDFFIT_DASK_SCHEDULER": cluster.scheduler_address}
        with Server(tmp_path / "srv", env=env) as srv, Client(srv.url) as c:
            path = write(tmp_path / "lambert.binary", table_bytes("lambert"))
            job = c.wait(c.fit(c.upload(path), "lambert", **FAST), timeout=300)
            assert job.status == "done", job
            assert c.result(job).params["kd"][0] == pytest.approx(0.5, rel=1e-3)
            assert c.plot(job, "spheres").startswith(b"\x89PNG")
        # the work ran on the cluster, not in a local worker process
        assert {"fit_models", "render_plot"} <= set(cluster.scheduler.task_prefixes)
