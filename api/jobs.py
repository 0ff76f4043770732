"""The fit job queue: SQLite holds the queue, a runner does the work.

The database, not memory, is the queue: a job is claimed by one atomic UPDATE
(``Store.claim_next``), so a server that dies at any instant loses nothing. At
start, :meth:`JobQueue.start` settles the jobs the last server left running
(re-queued while they have attempts left, else failed with the reason), then
``workers`` dispatch loops claim and run jobs until the server stops.

Each loop runs one job at a time, so the runner never holds more than ``workers``
fits and a plot request waits at most for one fit to end.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging

from api import tasks
from api.runner import AbstractRunner, WorkerLost
from api.store import JobRecord, Store

log = logging.getLogger("brdffit.api")

#: A dispatch loop looks at the database at least this often, whatever it is told.
POLL_S = 5.0


class JobQueue:
    def __init__(self, store: Store, runner: AbstractRunner, *, workers: int, max_attempts: int):
        self.store = store
        self.runner = runner
        self.workers = workers
        self.max_attempts = max_attempts
        self._wake = asyncio.Event()
        self._loops: list[asyncio.Task] = []

    async def start(self) -> None:
        requeued, failed = await asyncio.to_thread(self.store.recover, self.max_attempts)
        if requeued or failed:
            log.warning("recovered jobs of a stopped server: %d re-queued, %d failed",
                        len(requeued), len(failed))
        self._loops = [asyncio.create_task(self._dispatch(), name=f"fit-dispatch-{i}")
                       for i in range(self.workers)]

    async def stop(self) -> None:
        for loop in self._loops:
            loop.cancel()
        for loop in self._loops:
            with contextlib.suppress(asyncio.CancelledError):
                await loop
        self._loops = []
        released = await asyncio.to_thread(self.store.release_running)
        if released:
            log.info("shutdown: %d running job(s) back in the queue", released)

    def notify(self) -> None:
        """A job was queued: wake the idle loops."""
        self._wake.set()

    async def _dispatch(self) -> None:
        while True:
            job = await asyncio.to_thread(self.store.claim_next)
            if job is None:
                # Clear, then look once more: a notify() between the two is not lost.
                self._wake.clear()
                job = await asyncio.to_thread(self.store.claim_next)
            if job is None:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), POLL_S)
                continue
            await self._run(job)

    async def _run(self, job: JobRecord) -> None:
        table = await asyncio.to_thread(self.store.get_table, job.table_id)
        path = str(self.store.table_path(job.table_id))
        try:
            outcome = await self.runner.run(
                tasks.fit_models, path, table.name, job.models, job.options
            )
        except WorkerLost as e:
            status = await asyncio.to_thread(
                self.store.retry_or_fail, job.id, str(e), self.max_attempts
            )
            log.warning("job %s: %s; now %s", job.id, e, status)
            return
        except Exception as e:  # the runner itself failed: say so on the job
            log.exception("job %s: runner error", job.id)
            await asyncio.to_thread(self.store.fail, job.id, f"internal error: {e!r}")
            return
        if outcome["ok"]:
            await asyncio.to_thread(self.store.finish, job.id, outcome["results"])
        else:
            if "traceback" in outcome:
                log.error("job %s failed:\n%s", job.id, outcome["traceback"])
            await asyncio.to_thread(self.store.fail, job.id, outcome["reason"])
