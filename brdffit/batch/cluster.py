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

from brdffit import extras, models
from brdffit.batch.tasks import FitOptions, fit_one, raise_remote_error
from brdffit.fitting.result import FitResult

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


def require_dask() -> None:
    """Raise :class:`brdffit.extras.MissingExtraError` unless Dask is installed."""
    extras.require("batch", "a batch on Dask workers",
                   hint="workers=0, or --workers 0, fits in this process without Dask")


@contextlib.contextmanager
def connect(workers: int = 1, scheduler: str | None = None,
            timeout_s: float = 30.0) -> Iterator:
    """A ``distributed.Client``: to ``scheduler`` if given, else to ``workers`` local
    worker processes, shut down on exit."""
    require_dask()
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
    try:
        cluster = LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
            dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR,
            env=local_worker_env(workers),
            # Ctrl-C reaches these workers too (same process group): they ignore it
            # and are stopped by this process instead (brdffit.batch.local_worker).
            preload=["brdffit.batch.local_worker"],
        )
    except (RuntimeError, OSError, TimeoutError) as e:
        # e.g. "Nanny failed to start" where worker processes cannot start (a
        # container without /dev/shm): one line for the user, not distributed's
        # traceback
        cause = e.__cause__ or e
        raise OSError(f"cannot start {workers} local Dask worker process(es): "
                      f"{type(cause).__name__}: {cause}; --workers 0 fits in this "
                      "process without Dask") from None
    try:
        with Client(cluster, set_as_default=False) as client:
            yield client
    finally:
        cluster.close()


class WorkerLost(RuntimeError):
    """The Dask worker running a call died under it (killed, out of memory, crashed),
    and the scheduler gave up on it (``distributed.KilledWorker``)."""


class DaskRunner:
    """Calls on a Dask cluster, for a job runner that is not a batch (the REST service).

        runner = DaskRunner.from_env()         # None when BRDFFIT_DASK_SCHEDULER is unset
        fut = runner.submit_fit("/shared/gold.binary", "ggx", samples=8192)
        result: FitResult = fut.result()       # raises MerlFormatError etc. as fit would
        fut = runner.submit_call(some_module.top_level_fn, arg1, arg2)

    Both return ``concurrent.futures.Future`` (``asyncio.wrap_future`` makes them
    awaitable). A worker that dies under a call raises :class:`WorkerLost`. Bad
    models and options raise at once, as a local ``fit`` call would. Tables
    travel as paths the workers can read (shared storage) or, failing that, as
    bytes.
    """

    def __init__(self, address: str, *, timeout_s: float = 30.0):
        extras.require("batch", f"a Dask runner ({SCHEDULER_ENV})")
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

    def submit_call(self, fn, /, *args) -> concurrent.futures.Future:
        """``fn(*args)`` on a worker; ``fn`` must be importable there (a top-level
        function of an installed module) and its result picklable."""
        return self._bridge(self._client.submit(fn, *args, pure=False), lambda value: value)

    def submit_fit(self, source: str | bytes, model: str,
                   **fit_options) -> concurrent.futures.Future:
        """Fit ``model`` to the table at ``source`` (a path the workers can read, or
        the file's bytes). ``fit_options`` are ``fit``'s keyword arguments
        (solver, samples, precision, starts, max_steps, seed). The future's
        result is a :class:`brdffit.FitResult`."""
        name = models.get(model).name
        options = FitOptions.from_dict(fit_options)
        if isinstance(source, os.PathLike):
            source = os.fspath(source)
        elif isinstance(source, (bytes, bytearray, memoryview)):
            # 35 MB travels once, as data, not inside the task description.
            source = self._client.scatter(bytes(source), direct=True)
        remote = self._client.submit(fit_one, source, name, options.fit_keywords(), pure=False)

        def to_result(payload: dict) -> FitResult:
            if not payload["ok"]:
                raise_remote_error(payload["error"])
            return FitResult.from_dict(payload["fit"])

        return self._bridge(remote, to_result)

    def fit(self, source: str | bytes, model: str, *, timeout_s: float | None = None,
            **fit_options) -> FitResult:
        """Blocking form of :meth:`submit_fit`."""
        return self.submit_fit(source, model, **fit_options).result(timeout=timeout_s)

    @staticmethod
    def _bridge(remote, convert) -> concurrent.futures.Future:
        from distributed import KilledWorker

        done: concurrent.futures.Future = concurrent.futures.Future()

        def settle(f):
            try:
                done.set_result(convert(f.result()))
            except KilledWorker as e:
                done.set_exception(WorkerLost(f"the Dask worker running it died: {e}"))
            except BaseException as e:  # noqa: BLE001 - handed to the waiting caller
                done.set_exception(e)
            finally:
                f.release()

        remote.add_done_callback(settle)
        return done

    def close(self) -> None:
        self._client.close()

    def __enter__(self) -> DaskRunner:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
