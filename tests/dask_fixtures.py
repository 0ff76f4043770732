"""A Dask cluster started as an operator would: ``dask scheduler`` and ``dask worker``
processes of their own, on 127.0.0.1 (docs/batch.md, "On a real cluster").

Each process runs in its own session, so signals aimed at a batch or a server
under test never reach the cluster; every wait is bounded, and the processes are
stopped (then killed) on exit.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

from brdffit.batch.cluster import SINGLE_THREADED_XLA
from tests.api_fixtures import free_port

REPO = str(Path(__file__).resolve().parent.parent)


@contextlib.contextmanager
def separate_cluster(n_workers: int = 2, env: dict | None = None
                     ) -> Iterator[tuple[str, object]]:
    """``(address, client)``: a scheduler and ``n_workers`` single-threaded worker
    processes (each under its own nanny, which restarts it if it dies), and a
    ``distributed.Client`` to watch them; ``env``: their environment (default this
    process's, with the repository on the path)."""
    from distributed import Client

    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = env or {**os.environ, "PYTHONPATH": REPO}
    if n_workers > 1 and "XLA_FLAGS" not in env:
        # several on one machine: single-threaded XLA, as docs/batch.md says (flags the
        # developer set are theirs, as brdffit's own local workers leave them)
        env = {**env, "XLA_FLAGS": SINGLE_THREADED_XLA}
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler",
                               "--host", "127.0.0.1", "--port", str(port),
                               "--dashboard-address", "127.0.0.1:0"],
                              env=env, start_new_session=True, **quiet)]
    try:
        for _ in range(n_workers):
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads",
                 "1", "--host", "127.0.0.1", "--dashboard-address", "127.0.0.1:0"],
                env=env, start_new_session=True, **quiet))
        with Client(address, timeout=60, set_as_default=False) as client:
            client.wait_for_workers(n_workers, timeout=120)
            yield address, client
    finally:
        for p in reversed(procs):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.pid, signal.SIGKILL)
                p.wait(timeout=10)


def scheduler_tasks(dask_scheduler) -> int:
    """Tasks the scheduler holds (for ``client.run_on_scheduler``)."""
    return len(dask_scheduler.tasks)


def executing(dask_worker) -> int:
    """Tasks a worker is running (for ``client.run``)."""
    return len(dask_worker.state.executing)


def processing(dask_scheduler) -> dict[str, str]:
    """task key -> address of the worker running it."""
    return {str(ts.key): ts.processing_on.address for ts in dask_scheduler.tasks.values()
            if ts.processing_on is not None}
