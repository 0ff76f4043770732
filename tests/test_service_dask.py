"""The service on an existing Dask cluster (``BRDFFIT_DASK_SCHEDULER``): its jobs run
on the cluster's workers through the batch job's runner, results and plots as on
local workers."""

from __future__ import annotations

import pytest

from brdffit.batch.cluster import local_cluster_options
from brdffit.client import Client
from tests.api_fixtures import FAST, Server, table_bytes, write

pytestmark = pytest.mark.system


def test_jobs_run_on_the_dask_cluster(tmp_path):
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0", **local_cluster_options(1)) as cluster:
        env = {"BRDFFIT_DASK_SCHEDULER": cluster.scheduler_address}
        with Server(tmp_path / "srv", env=env) as srv, Client(srv.url) as c:
            path = write(tmp_path / "lambert.binary", table_bytes("lambert"))
            job = c.wait(c.fit(c.upload(path), "lambert", **FAST), timeout=300)
            assert job.status == "done", job
            assert c.result(job).params["kd"][0] == pytest.approx(0.5, rel=1e-3)
            assert c.plot(job, "spheres").startswith(b"\x89PNG")
        # the work ran on the cluster, not in a local worker process
        assert {"fit_models", "render_plot"} <= set(cluster.scheduler.task_prefixes)


def test_a_worker_killed_mid_job_on_a_separate_cluster_the_job_ends_once(tmp_path):
    """docs/service.md, "On a Dask cluster": the service with BRDFFIT_DASK_SCHEDULER
    pointing at a separately started scheduler and two workers. A worker is killed
    (SIGKILL) while it runs the job; Dask runs the task again on the other worker,
    and the job ends once: done, on its first attempt, one result per model."""
    import os
    import signal
    import time

    import httpx

    from tests.api_fixtures import wait_status
    from tests.dask_fixtures import processing, separate_cluster

    with separate_cluster(2) as (address, dask), \
            Server(tmp_path / "srv", env={"BRDFFIT_DASK_SCHEDULER": address}) as srv, \
            httpx.Client(base_url=srv.url, timeout=60) as http:
        table = http.post("/v1/tables", content=table_bytes("ggx"),
                          headers={"content-type": "application/octet-stream"}).json()["id"]
        # running for seconds when the worker is killed: a fresh worker imports JAX and
        # loads its programs before it fits ggx, then ggx2 from it (auto, api_fixtures.SLOW_JOB,
        # fits seven models twice: twice this test's time, for nothing more to see)
        answer = http.post("/v1/fits", json={"table_id": table, "model": "ggx2"})
        assert answer.status_code == 202, answer.text
        job_id = answer.json()["id"]
        deadline = time.monotonic() + 300
        while not (running := {k: w for k, w in dask.run_on_scheduler(processing).items()
                               if k.startswith("fit_models")}):
            assert time.monotonic() < deadline, http.get(f"/v1/fits/{job_id}").json()
            time.sleep(0.2)
        (worker,) = running.values()
        pid = dask.run(os.getpid, workers=[worker])[worker]
        assert pid != srv.proc.pid
        os.kill(pid, signal.SIGKILL)
        # Dask runs the task again on a live worker (the other one, or the killed one
        # restarted by its nanny under a new address)
        deadline = time.monotonic() + 300
        while not {w for k, w in dask.run_on_scheduler(processing).items()
                   if k.startswith("fit_models")} - {worker}:
            assert http.get(f"/v1/fits/{job_id}").json()["status"] == "running"
            assert time.monotonic() < deadline
            time.sleep(0.2)

        job = wait_status(http, job_id, ("done", "failed", "cancelled"), timeout=900)
        assert job["status"] == "done", job
        assert job["attempts"] == 1 and not job["reason"], job  # not retried by the service
        assert [r["model"] for r in job["results"]] == ["ggx2"], job["results"]
        listing = http.get("/v1/fits").json()
        assert listing["total"] == 1 and listing["items"][0]["id"] == job_id
