"""Where the service's library calls run: never on the event loop.

:class:`AbstractRunner` is the whole contract the job queue and the plot route
rely on: ``await runner.run(fn, *args)`` runs a top-level function of
``api.tasks`` somewhere else and returns its value, and stops it when asked
(``cancel``) or when it runs too long (``limit_s``). :class:`ProcessRunner` keeps
``workers`` local processes; :class:`DaskClusterRunner` runs them on an existing
Dask cluster (``BRDFFIT_DASK_SCHEDULER``) through the batch job's runner.

Each worker process has its own pipe and runs one task at a time, so the runner
knows which task each process holds: a process that dies fails only its own task
(:class:`WorkerLost`), and stopping one task kills only its process. (A
``ProcessPoolExecutor`` cannot do either: one dead process breaks the pool and
every task in it, and it cannot stop a running task.)
"""

from __future__ import annotations

import abc
import asyncio
import contextlib
import logging
import multiprocessing
import os
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from api import tasks
from api.settings import Settings

log = logging.getLogger("brdffit.api")

#: ``progress(stage, fraction)``, awaited for each report a task makes.
OnProgress = Callable[[str, float], Awaitable[None]]


class Stopped(RuntimeError):
    """A task did not complete: its process died, or was stopped on purpose."""


class WorkerLost(Stopped):
    """The process running a task died (killed, out of memory, crashed)."""


class TimeLimitExceeded(Stopped):
    """The task ran past its time limit and its process was stopped."""


class Cancelled(Stopped):
    """The task was cancelled on request and its process was stopped."""


class AbstractRunner(abc.ABC):
    @abc.abstractmethod
    async def run(self, fn: Callable[..., Any], /, *args: Any, progress: OnProgress | None = None,
                  limit_s: float | None = None, cancel: asyncio.Event | None = None) -> Any:
        """``fn(*args)`` away from the event loop. Raises :class:`WorkerLost` if the
        worker dies under it, :class:`TimeLimitExceeded` after ``limit_s`` seconds,
        :class:`Cancelled` once ``cancel`` is set; ``progress`` gets the task's
        reports (``api.tasks.report``)."""

    def start(self) -> None:
        """Optional: get ready before the first task (e.g. start workers)."""

    @abc.abstractmethod
    def close(self) -> None:
        """Stop now; tasks still running are abandoned."""


#: How long a clean stop waits for an idle worker to exit when told (one waiting for a
#: task exits in milliseconds).
IDLE_EXIT_S = 0.25


class _Worker:
    """One 'spawn' process and the parent's end of its pipe. JAX is not fork-safe
    once initialised, and the server process has imported it."""

    def __init__(self, ctx) -> None:
        self.conn, child = ctx.Pipe(duplex=True)
        self.process = ctx.Process(target=tasks.serve, args=(child, os.getpid()),
                                   name="brdffit-worker", daemon=True)
        self.process.start()
        child.close()  # else the parent holds the child's end and never sees EOF

    @property
    def pid(self) -> int | None:
        return self.process.pid

    def receive(self) -> tuple:
        """The next message, blocking (run in a thread); EOFError once the process is gone."""
        return self.conn.recv()

    def kill(self) -> None:
        if self.process.is_alive():
            self.process.kill()
        self.process.join(timeout=5.0)
        self.conn.close()

    def stop(self, timeout: float) -> None:
        """Ask an idle worker to exit; kill it if it does not within ``timeout``."""
        with contextlib.suppress(OSError, ValueError):
            self.conn.send(None)
        self.process.join(timeout=timeout)
        self.kill()


def _retrieve(future: asyncio.Future) -> None:
    """Mark a future's outcome as seen: a task that is abandoned on purpose."""
    if not future.cancelled():
        future.exception()


class ProcessRunner(AbstractRunner):
    """``workers`` processes, each running one task at a time."""

    def __init__(self, workers: int):
        self.workers = workers
        self._ctx = multiprocessing.get_context("spawn")
        self._idle: asyncio.Queue[_Worker] | None = None
        self._all: set[_Worker] = set()
        self._closed = False
        # Threads that wait on the workers' pipes, one per busy worker: their own
        # pool, since a fit holds one for minutes, and asyncio's default pool (a few
        # threads on a small machine) also runs the job queue's database calls.
        self._readers = ThreadPoolExecutor(max_workers=workers + 2,
                                           thread_name_prefix="worker-pipe")

    def start(self) -> None:
        # Spawn now (each imports JAX and matplotlib before its first task), not when
        # the first fit arrives.
        self._idle = asyncio.Queue()
        for _ in range(self.workers):
            self._idle.put_nowait(self._spawn())

    def _spawn(self) -> _Worker:
        worker = _Worker(self._ctx)
        self._all.add(worker)
        return worker

    def _replace(self, worker: _Worker) -> None:
        worker.kill()
        self._all.discard(worker)
        if not self._closed:
            self._idle.put_nowait(self._spawn())

    async def run(self, fn, /, *args, progress=None, limit_s=None, cancel=None):
        if self._idle is None:
            self.start()
        worker = await self._idle.get()
        try:
            worker.conn.send((fn, args))
        except (OSError, ValueError):  # died while idle
            self._replace(worker)
            raise WorkerLost("the worker process died before it could start the task") from None
        loop = asyncio.get_running_loop()
        deadline = None if limit_s is None else loop.time() + limit_s
        waiter = asyncio.ensure_future(cancel.wait()) if cancel is not None else None
        message = None
        try:
            while True:
                message = loop.run_in_executor(self._readers, worker.receive)
                left = None if deadline is None else max(deadline - loop.time(), 0.0)
                await asyncio.wait([message] + ([waiter] if waiter else []), timeout=left,
                                   return_when=asyncio.FIRST_COMPLETED)
                if not message.done():
                    # Cancelled or out of time: stop the process, and with it the
                    # thread blocked on its pipe.
                    why = (Cancelled("cancelled on request") if waiter and waiter.done()
                           else TimeLimitExceeded(f"ran past its time limit of {limit_s:g} s"))
                    self._replace(worker)
                    with contextlib.suppress(EOFError, OSError):
                        await message
                    raise why
                try:
                    kind, *body = message.result()
                except (EOFError, OSError):
                    self._replace(worker)
                    code = worker.process.exitcode
                    raise WorkerLost("the worker process died (killed, out of memory or "
                                     f"crashed; exit code {code})") from None
                if kind == "progress":
                    if progress is not None:
                        await progress(*body)
                    continue
                self._idle.put_nowait(worker)
                if kind == "value":
                    return body[0]
                raise RuntimeError(f"task {fn.__name__} raised {body[0]}")  # kind == "error"
        except asyncio.CancelledError:
            # The caller went away (server stopping): the task's process is of no use.
            self._replace(worker)
            if message is not None:
                # The pipe reader now ends with EOFError from the killed process, and
                # no one awaits it any more: retrieve it, or asyncio logs "Future
                # exception was never retrieved" with a traceback at every clean stop.
                message.add_done_callback(_retrieve)
            raise
        finally:
            if waiter is not None:
                waiter.cancel()

    def pids(self) -> list[int]:
        """The worker processes' ids (for the tests that kill one)."""
        return [w.pid for w in self._all if w.pid is not None]

    def close(self) -> None:
        # A clean stop does not wait out a long fit: its job is back in the queue
        # (Store.release_running). Idle workers exit when told, at once where they wait
        # for a task; one still starting (importing JAX, ~1.5 s) holds nothing yet and
        # is killed after IDLE_EXIT_S rather than waited for (a server stopped just
        # after its start took 1.7 s to stop, 0.45 s so). Busy ones are killed.
        self._closed = True
        idle = set()
        while self._idle is not None and not self._idle.empty():
            idle.add(self._idle.get_nowait())
        for worker in self._all:
            if worker in idle:
                worker.stop(timeout=IDLE_EXIT_S)
            else:
                worker.kill()
        self._all.clear()
        self._readers.shutdown(wait=False)


class DaskClusterRunner(AbstractRunner):
    """The service's tasks on an existing Dask cluster, through the batch job's own
    runner (:class:`brdffit.batch.cluster.DaskRunner`): one way to reach a cluster
    for both. The workers must read the service's data directory at the same path.

    What Dask cannot do, and what happens instead: a running Dask task cannot be
    interrupted, so ``cancel`` and ``limit_s`` end the job at once (the
    :class:`Cancelled` / :class:`TimeLimitExceeded` it raises) while the worker
    finishes the call and its result is dropped; a worker process reports no
    progress to the server, so a running job's progress stays at its start.
    """

    def __init__(self, address: str):
        from brdffit.batch.cluster import DaskRunner

        self._dask = DaskRunner(address)

    async def run(self, fn, /, *args, progress=None, limit_s=None, cancel=None):
        from brdffit.batch.cluster import DaskWorkerLost

        if progress is not None:
            await progress("running on the Dask cluster", 0.0)
        done = asyncio.ensure_future(asyncio.wrap_future(self._dask.submit_call(fn, *args)))
        waiters = {done}
        stop = asyncio.ensure_future(cancel.wait()) if cancel is not None else None
        if stop is not None:
            waiters.add(stop)
        try:
            finished, _ = await asyncio.wait(waiters, timeout=limit_s,
                                             return_when=asyncio.FIRST_COMPLETED)
        finally:
            if stop is not None:
                stop.cancel()
        if done in finished:
            try:
                return done.result()
            except DaskWorkerLost as e:
                raise WorkerLost(str(e)) from e
        done.cancel()
        if stop is not None and stop in finished:
            raise Cancelled("cancelled on request (the Dask worker finishes the call)")
        raise TimeLimitExceeded(f"ran past {limit_s:g} s (the Dask worker finishes the call)")

    def close(self) -> None:
        self._dask.close()


def make_runner(settings: Settings) -> AbstractRunner:
    """The runner the settings ask for: an existing Dask cluster when
    ``dask_scheduler`` is set, else ``workers`` local processes."""
    if settings.dask_scheduler:
        return DaskClusterRunner(settings.dask_scheduler)
    return ProcessRunner(settings.workers)
