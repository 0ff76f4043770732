"""Where the service's library calls run: never on the event loop.

:class:`AbstractRunner` is the whole contract the job queue and the plot route
rely on: ``await runner.run(fn, *args)`` runs a top-level function of
``api.tasks`` somewhere else and returns its value. :class:`ProcessRunner` uses a
local pool of worker processes. A Dask runner (``BRDFFIT_DASK_SCHEDULER``,
issue 5) is one more subclass whose ``run`` submits to a
``distributed.Client``, plus one branch in :func:`make_runner`.
"""

from __future__ import annotations

import abc
import asyncio
import logging
import multiprocessing
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from api import tasks
from api.settings import Settings

log = logging.getLogger("brdffit.api")


class WorkerLost(RuntimeError):
    """The process running a task died (killed, out of memory, crashed)."""


class AbstractRunner(abc.ABC):
    @abc.abstractmethod
    async def run(self, fn: Callable[..., Any], /, *args: Any) -> Any:
        """``fn(*args)`` away from the event loop; raises :class:`WorkerLost` if
        the worker dies under it."""

    def start(self) -> None:
        """Optional: get ready before the first task (e.g. start workers)."""

    @abc.abstractmethod
    def close(self) -> None:
        """Stop now; tasks still running are abandoned."""


class ProcessRunner(AbstractRunner):
    """A pool of ``workers`` processes, started with 'spawn': JAX is not fork-safe
    once initialised, and the server process has imported it."""

    def __init__(self, workers: int):
        self.workers = workers
        self._pool = self._new_pool()

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=self.workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=tasks.start_worker,
            initargs=(os.getpid(),),
        )

    def start(self) -> None:
        # Spawn and import in every worker now, not when the first fit arrives.
        for _ in range(self.workers):
            self._pool.submit(tasks.warm_up)

    async def run(self, fn, /, *args):
        pool = self._pool
        try:
            return await asyncio.wrap_future(pool.submit(fn, *args))
        except BrokenProcessPool as e:
            # A dead worker breaks the whole pool: replace it (once, whoever sees it
            # first) so that the next task runs.
            if pool is self._pool:
                log.warning("a worker process died; starting a new pool")
                self._pool = self._new_pool()
                pool.shutdown(wait=False, cancel_futures=True)
            raise WorkerLost("the worker process died (killed, out of memory or crashed)") from e

    def close(self) -> None:
        pool = self._pool
        processes = list(getattr(pool, "_processes", {}).values())
        pool.shutdown(wait=False, cancel_futures=True)  # idle workers exit at once
        # A clean stop should not wait out a long fit: its job is back in the queue
        # (Store.release_running). Python 3.11 has no terminate_workers().
        for process in processes:
            process.join(timeout=2.0)
            if process.is_alive():
                process.terminate()


def make_runner(settings: Settings) -> AbstractRunner:
    """The runner the settings ask for (only local processes for now)."""
    return ProcessRunner(settings.workers)
