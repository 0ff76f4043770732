"""The Dask side of batch fitting: a local cluster, a remote one, and single fits for the service.

- :func:`connect` gives a ``distributed.Client``: to an existing scheduler
  (``tcp://HOST:PORT``) or to a fresh ``LocalCluster`` of worker *processes* on
  loopback, one thread each (a JAX fit already uses the cores it is given; two
  fits in one process would only contend for its XLA threads), single-threaded
  when there are several (:func:`local_worker_env`).
- :class:`DaskRunner` runs one fit on a cluster for a job runner that is not a
  batch (the REST service): ``DaskRunner.from_env()`` reads
  ``BRDFFIT_DASK_SCHEDULER``.

Work items are paths: workers read tables from storage they share with the
client, and each worker process keeps its compiled fits for every later table.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import logging
import os
from collections.abc import Iterator

from . import models
from .batch_tasks import FitOptions, fit_one, raise_remote_error
from .fitting import FitResult

SCHEDULER_ENV = "BRDFFIT_DASK_SCHEDULER"
#: XLA's CPU backend spreads one fit over every core it sees. Several worker
#: processes doing that on the same cores fight: measured here, 2 workers on 2
#: cores fitted no faster than 1 until each was made single-threaded.
SINGLE_THREADED_XLA = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"


def local_worker_env(workers: int, environ=os.environ) -> dict[str, str]:
    """Environment for local worker processes: single-threaded XLA when there are
    several of them, unless the user chose ``XLA_FLAGS`` already."""
    if workers > 1 and "XLA_FLAGS" not in environ:
        return {"XLA_FLAGS": SINGLE_THREADED_XLA}
    return {}


@contextlib.contextmanager
def connect(workers: int = 1, scheduler: str | None = None,
            timeout_s: float = 30.0) -> Iterator:
    """A ``distributed.Client``: to ``scheduler`` if given, else to ``workers`` local
    worker processes, shut down on exit."""
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout=timeout_s, set_as_default=False)
        except (OSError, TimeoutError) as e:
            raise OSError(f"cannot reach the Dask scheduler at {scheduler}: {e}") from None
        with client:
            yield client
        return
    if workers < 1:
        raise ValueError(f"a local cluster needs at least 1 worker, got {workers}")
    cluster = LocalCluster(
        n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
        dashboard_address=None, silence_logs=logging.ERROR, env=local_worker_env(workers),
    )
    try:
        with Client(cluster, set_as_default=False) as client:
            yield client
    finally:
        cluster.close()


class DaskRunner:
    """Single fits on a Dask cluster, for a service's job runner.

        runner = DaskRunner.from_env()          # None when BRDFFIT_DASK_SCHEDULER is unset
        future = runner.submit("/shared/gold.binary", "ggx", samples=8192)
        result: FitResult = future.result()     # raises MerlFormatError etc. as fit would

    ``submit`` returns a ``concurrent.futures.Future``; bad models and options
    raise at once, as a local ``fit`` call would.
    """

    def __init__(self, address: str, *, timeout_s: float = 30.0):
        from distributed import Client

        self.address = address
        try:
            self._client = Client(address, timeout=timeout_s, set_as_default=False)
        except (OSError, TimeoutError) as e:
            raise OSError(f"cannot reach the Dask scheduler at {address}: {e}") from None

    @classmethod
    def from_env(cls, environ=os.environ) -> DaskRunner | None:
        address = environ.get(SCHEDULER_ENV, "").strip()
        return cls(address) if address else None

    def submit(self, source: str | bytes, model: str, **fit_options) -> concurrent.futures.Future:
        """Fit ``model`` to the table at ``source`` (a path the workers can read, or
        the file's bytes). ``fit_options`` are ``fit``'s keyword arguments
        (solver, samples, precision, starts, max_steps, seed)."""
        name = models.get(model).name
        options = FitOptions(**fit_options).validate()
        if isinstance(source, os.PathLike):
            source = os.fspath(source)
        elif isinstance(source, (bytes, bytearray, memoryview)):
            # 35 MB travels once, as data, not inside the task description.
            source = self._client.scatter(bytes(source), direct=True)
        remote = self._client.submit(fit_one, source, name, options.to_dict(), pure=False)
        done: concurrent.futures.Future = concurrent.futures.Future()

        def settle(f):
            try:
                payload = f.result()
                if not payload["ok"]:
                    raise_remote_error(payload["error"])
                done.set_result(FitResult.from_dict(payload["fit"]))
            except BaseException as e:  # noqa: BLE001 - handed to the waiting caller
                done.set_exception(e)
            finally:
                f.release()

        remote.add_done_callback(settle)
        return done

    def fit(self, source: str | bytes, model: str, *, timeout_s: float | None = None,
            **fit_options) -> FitResult:
        """Blocking form of :meth:`submit`."""
        return self.submit(source, model, **fit_options).result(timeout=timeout_s)

    def close(self) -> None:
        self._client.close()

    def __enter__(self) -> DaskRunner:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
