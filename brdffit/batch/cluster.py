"""The Dask side of batch fitting: a local cluster, a remote one, and single calls for the service.

- :func:`connect` gives a ``distributed.Client``: to an existing scheduler
  (``tcp://HOST:PORT``) or to a fresh ``LocalCluster`` of worker *processes* on
  loopback, one thread each (a JAX fit already uses the cores it is given; two
  fits in one process would only contend for its XLA threads), each on its own
  share of the cores when there are several (:func:`local_worker_env`,
  ``brdffit.batch.local_worker``).
- :class:`DaskRunner` runs one call on a cluster for a job runner that is not a
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
import signal
import socket
import sys
import threading
import time
from collections.abc import Iterator

from brdffit import extras

SCHEDULER_ENV = "BRDFFIT_DASK_SCHEDULER"
# how long a refused scheduler address is tried again before it is refused: a
# scheduler started just before the batch takes a few seconds to listen
REFUSED_GRACE_S = 5.0
#: XLA's CPU backend spreads one fit over every core it sees. Several worker
#: processes doing that on the same cores fight: measured here, 2 workers on 2
#: cores fitted no faster than 1 until each was made single-threaded. Workers
#: started by hand (``dask worker --nworkers N`` on one machine, docs/batch.md) are
#: made so with these flags.
SINGLE_THREADED_XLA = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
#: How many local workers share this machine's cores: set for them by
#: :func:`local_worker_env`, read by ``brdffit.batch.local_worker`` as each starts.
LOCAL_WORKERS_ENV = "BRDFFIT_LOCAL_WORKERS"


def local_worker_env(workers: int, environ=os.environ) -> dict[str, str]:
    """Environment for local worker processes, when there are several: their count,
    by which each worker (``brdffit.batch.local_worker``) takes its own share of the
    cores; unless the user chose ``XLA_FLAGS``, which are then left to decide.

    Not ``XLA_FLAGS`` of ours: they are part of the compiled programs' fingerprint
    (``brdffit.executables``), so workers with them could not load what ``brdffit
    warmup`` and every other process compiled, and compiled it all again."""
    if workers > 1 and "XLA_FLAGS" not in environ:
        return {LOCAL_WORKERS_ENV: str(workers)}
    return {}


def local_cluster_options(workers: int, environ=os.environ) -> dict:
    """The ``LocalCluster`` keywords that make its ``workers`` worker processes
    brdffit's: their environment, and ``brdffit.batch.local_worker`` preloaded
    (each takes its share of the cores and ignores Ctrl-C)."""
    return {"env": local_worker_env(workers, environ),
            "preload": ["brdffit.batch.local_worker"]}


def require_dask() -> None:
    """Raise :class:`brdffit.extras.MissingExtraError` unless Dask is installed."""
    extras.require("batch", "a batch on Dask workers",
                   hint="workers=0, or --workers 0, fits in this process without Dask")


#: How long a scheduler's address is given to answer Dask's handshake
#: (:func:`scheduler_client`): distributed's own default connect timeout.
CONNECT_TIMEOUT_S = 30.0


@contextlib.contextmanager
def connect(workers: int = 1, scheduler: str | None = None,
            timeout_s: float = CONNECT_TIMEOUT_S,
            listening: threading.Event | None = None) -> Iterator:
    """A ``distributed.Client``: to ``scheduler`` if given, else to ``workers`` local
    worker processes, shut down on exit. ``listening``: set once the scheduler's address
    takes the connection (:func:`scheduler_client`)."""
    require_dask()
    from distributed import Client, LocalCluster

    if scheduler:
        with scheduler_client(scheduler, timeout_s, listening) as client:
            yield client
        return
    if workers < 1:
        raise ValueError(f"a local cluster needs at least 1 worker, got {workers}")
    # Ctrl-C at a terminal signals the whole process group, the workers too; they
    # ignore it once started (brdffit.batch.local_worker), but one pressed while they
    # still imported printed each one's KeyboardInterrupt traceback. SIGINT is held
    # (blocked, not lost) while the cluster starts: the threads it starts, and the
    # worker processes they start, inherit the blocked signal, and this process takes
    # it once the cluster can be closed, as any Ctrl-C during the batch
    held = _hold_sigint()
    try:
        cluster = LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
            dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR,
            **local_cluster_options(workers),
        )
    except (RuntimeError, OSError, TimeoutError) as e:
        _release_sigint(held)
        # e.g. "Nanny failed to start" where worker processes cannot start (a
        # container without /dev/shm): one line for the user, not distributed's
        # traceback
        cause = e.__cause__ or e
        raise OSError(f"cannot start {workers} local Dask worker process(es): "
                      f"{type(cause).__name__}: {cause}; --workers 0 fits in this "
                      "process without Dask") from None
    except BaseException:
        _release_sigint(held)
        raise
    try:
        _release_sigint(held)
        with Client(cluster, set_as_default=False) as client:
            yield client
    finally:
        cluster.close()


def _hold_sigint() -> bool:
    """Block SIGINT in the main thread; True where the caller unblocks it again."""
    if (threading.current_thread() is not threading.main_thread()
            or not hasattr(signal, "pthread_sigmask")):  # Windows: no signal masks
        return False
    # multiprocessing's resource tracker, started by the first worker process, blocks
    # SIGINT around its own start and then unblocks it in the thread that started it
    # (the cluster's): started here first, it leaves the mask alone. Its warning at
    # exit of "leaked semaphore objects to clean up", after a Ctrl-C while the workers
    # start, is of the queues it then cleans up: nothing is left, and nothing to say
    from multiprocessing import resource_tracker

    saved = list(sys.warnoptions)  # the tracker's -W options are these, when it starts
    sys.warnoptions.append("ignore:resource_tracker:UserWarning")
    try:
        resource_tracker.ensure_running()
    finally:
        sys.warnoptions[:] = saved
    return signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})


def _release_sigint(held: bool) -> None:
    # a Ctrl-C pressed meanwhile is delivered here (KeyboardInterrupt in the main thread)
    if held:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def scheduler_client(address: str, timeout_s: float = CONNECT_TIMEOUT_S,
                     listening: threading.Event | None = None):
    """A ``distributed.Client`` of the scheduler at ``address``, or an ``OSError`` that
    says why there is none: nothing listens there (:func:`_refused`), or something does
    and does not answer as a Dask scheduler within ``timeout_s`` (:func:`_silent`), or
    the client's own error. ``listening`` is set once nothing refuses the connection:
    what is left to wait for is the answer (up to ``timeout_s``)."""
    from distributed import Client

    refused = _refused(address)
    if not refused and listening is not None:
        listening.set()
    why = f"nothing listens there ({refused})" if refused else _silent(address, timeout_s)
    if why:
        raise OSError(f"cannot reach the Dask scheduler at {address}: {why}")
    try:
        return Client(address, timeout=timeout_s, set_as_default=False)
    except (OSError, TimeoutError) as e:
        raise OSError(f"cannot reach the Dask scheduler at {address}: {e}") from None


def _silent(address: str, timeout_s: float) -> str | None:
    """Why ``address`` is no Dask scheduler though it took the connection, else None:
    it did not complete Dask's handshake within ``timeout_s`` seconds. distributed's
    connect timeout leaves the handshake out (dask/distributed#7698), and
    ``Client(address, timeout=30)`` waited for good on a port that accepts and never
    answers (another service on that port, a stopped process whose socket is still
    open). The probe is distributed's own ``connect``, on a thread of its own (the
    service calls this inside its event loop), so no detail of the protocol is
    assumed here; other errors are left to the client."""
    import asyncio

    from distributed.comm import connect

    async def handshake() -> None:
        comm = await asyncio.wait_for(connect(address, timeout=timeout_s), timeout_s)
        await comm.close()

    done: concurrent.futures.Future = concurrent.futures.Future()

    def probe() -> None:
        try:
            done.set_result(asyncio.run(handshake()))
        except BaseException as e:  # noqa: BLE001 - handed to the waiting thread
            done.set_exception(e)

    # a daemon thread: a Ctrl-C meanwhile ends the process without waiting it out
    threading.Thread(target=probe, name="dask-probe", daemon=True).start()
    try:
        done.result()
    except TimeoutError:
        return (f"something listens there but did not answer as a Dask scheduler "
                f"within {timeout_s:g} s (another service on that port?)")
    except Exception:  # noqa: BLE001 - refused, reset, a bad address: the client says
        return None
    return None


def _refused(address: str, grace_s: float = REFUSED_GRACE_S) -> str | None:
    """Why a TCP connection to ``address`` was refused (nothing listens at that port)
    throughout ``grace_s`` seconds, else None: the client retries a refused address
    until its timeout, and said "Timed out" after 30 s of it. The grace is for a
    scheduler started a moment before (``dask scheduler & brdffit batch ...``), which
    takes a few seconds to listen. Other protocols, and other errors (a host that does
    not answer), are left to the client."""
    from distributed.comm import parse_address, parse_host_port

    try:
        protocol, location = parse_address(address)
        host, port = parse_host_port(location)
    except (ValueError, TypeError):
        return None  # the client says what is wrong with it
    if protocol not in ("tcp", "tls"):
        return None
    deadline = time.monotonic() + grace_s
    while True:
        try:
            with socket.create_connection((host, port), timeout=5.0):
                return None
        except ConnectionRefusedError as e:
            if time.monotonic() >= deadline:
                return f"{e.strerror or 'connection refused'} for {grace_s:g} s"
            time.sleep(0.25)
        except OSError:
            return None


class DaskWorkerLost(RuntimeError):
    """The Dask worker running a call died under it (killed, out of memory, crashed),
    and the scheduler gave up on it (``distributed.KilledWorker``)."""


class DaskRunner:
    """Calls on a Dask cluster, for a job runner that is not a batch (the REST service).

        runner = DaskRunner.from_env()         # None when BRDFFIT_DASK_SCHEDULER is unset
        fut = runner.submit_call(api.tasks.fit_models, path, name, request)

    It returns a ``concurrent.futures.Future`` (``asyncio.wrap_future`` makes it
    awaitable); the service's tasks return an ``Outcome`` rather than raise. A worker
    that dies under a call raises :class:`DaskWorkerLost`.
    """

    def __init__(self, address: str, *, timeout_s: float = CONNECT_TIMEOUT_S):
        extras.require("batch", f"a Dask runner ({SCHEDULER_ENV})")
        self.address = address
        self._client = scheduler_client(address, timeout_s)

    @classmethod
    def from_env(cls, environ=os.environ) -> DaskRunner | None:
        address = environ.get(SCHEDULER_ENV, "").strip()
        return cls(address) if address else None

    def submit_call(self, fn, /, *args) -> concurrent.futures.Future:
        """``fn(*args)`` on a worker; ``fn`` must be importable there (a top-level
        function of an installed module) and its result picklable."""
        return self._bridge(self._client.submit(fn, *args, pure=False), lambda value: value)

    @staticmethod
    def _bridge(remote, convert) -> concurrent.futures.Future:
        from distributed import KilledWorker

        done: concurrent.futures.Future = concurrent.futures.Future()

        def settle(f):
            try:
                done.set_result(convert(f.result()))
            except KilledWorker as e:
                done.set_exception(DaskWorkerLost(f"the Dask worker running it died: {e}"))
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
