"""The fit job queue: SQLite holds the queue, a runner does the work.

The database, not memory, is the queue: a job is claimed by one atomic UPDATE
(``Store.claim_next``), so a server that dies at any instant loses nothing. At
start, :meth:`JobQueue.start` settles the jobs the last server left running
(re-queued while they have attempts left, else failed with the reason), then
``workers`` dispatch loops claim and run jobs until the server stops.

Each loop runs one job at a time, so the runner never holds more than ``workers``
fits and a plot request waits at most for one fit to end.

Supervision: a dispatch loop never dies of a storage error. It waits and tries
again (with backoff) and, while it cannot make progress, says why in
:attr:`JobQueue.problems`, which ``/healthz`` reports (not ready). A finished
job's outcome is written again and again for ``BRDFFIT_STORAGE_RETRY_S``; after
that the job is failed with the reason, if the storage takes even that.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable

from api import tasks
from api.runner import AbstractRunner, Cancelled, TimeLimitExceeded, WorkerLost
from api.settings import Settings
from api.store import JobRecord, Store

log = logging.getLogger("brdffit.api")

#: A dispatch loop looks at the database at least this often, whatever it is told.
POLL_S = 5.0
#: Waits between tries of a failing storage call: 0.25 s doubling up to this.
MAX_BACKOFF_S = 5.0


class JobQueue:
    def __init__(self, store: Store, runner: AbstractRunner, settings: Settings):
        self.store = store
        self.runner = runner
        self.settings = settings
        self.workers = settings.workers
        self.max_attempts = settings.max_attempts
        #: What stops a dispatch loop now, by loop name: empty when all is well.
        self.problems: dict[str, str] = {}
        self._wake = asyncio.Event()
        self._loops: list[asyncio.Task] = []
        self._running: dict[str, asyncio.Event] = {}  # job id -> its cancel signal
        self._cancel_wanted: set[str] = set()

    async def start(self) -> None:
        requeued, failed = await asyncio.to_thread(self.store.recover, self.max_attempts)
        if requeued or failed:
            log.warning("recovered jobs of a stopped server: %d re-queued, %d failed",
                        len(requeued), len(failed))
        self._loops = [asyncio.create_task(self._dispatch(f"dispatch-{i}"),
                                           name=f"fit-dispatch-{i}")
                       for i in range(self.workers)]

    async def stop(self) -> None:
        for loop in self._loops:
            loop.cancel()
        for loop in self._loops:
            with contextlib.suppress(asyncio.CancelledError):
                await loop
        self._loops = []
        try:
            released = await asyncio.to_thread(self.store.release_running)
        except Exception as e:  # the next start settles them instead (Store.recover)
            log.error("shutdown: could not put running jobs back in the queue: %s", e)
        else:
            if released:
                log.info("shutdown: %d running job(s) back in the queue", released)

    def notify(self) -> None:
        """A job was queued: wake the idle loops."""
        self._wake.set()

    def cancel_running(self, job_id: str) -> None:
        """Stop a running job (the route has found it running): its worker is
        stopped and the job marked cancelled by its dispatch loop."""
        self._cancel_wanted.add(job_id)
        if job_id in self._running:
            self._running[job_id].set()

    @property
    def alive(self) -> bool:
        """Every dispatch loop still runs (a loop that died is a bug: say so)."""
        return all(not loop.done() for loop in self._loops)

    # -- storage, supervised ---------------------------------------------------------

    async def _store(self, name: str, what: str, call: Callable, *args,
                     give_up_after: float | None = None):
        """``call(*args)`` in a thread, tried again with backoff while the storage
        fails (the reason in :attr:`problems` meanwhile). Raises the last error
        after ``give_up_after`` seconds (None: never gives up)."""
        backoff, since = 0.25, time.monotonic()
        while True:
            try:
                value = await asyncio.to_thread(call, *args)
            except Exception as e:
                problem = f"cannot {what}: {type(e).__name__}: {e}"
                if self.problems.get(name) != problem:
                    log.error("%s: %s; trying again", name, problem)
                self.problems[name] = problem
                if give_up_after is not None and time.monotonic() - since > give_up_after:
                    raise
                await asyncio.sleep(backoff)
                backoff = min(2 * backoff, MAX_BACKOFF_S)
                continue
            if self.problems.pop(name, None) is not None:
                log.warning("%s: storage works again", name)
            return value

    # -- the loops -------------------------------------------------------------------

    async def _dispatch(self, name: str) -> None:
        while True:
            job = await self._store(name, "claim the next job", self.store.claim_next)
            if job is None:
                # Clear, then look once more: a notify() between the two is not lost.
                self._wake.clear()
                job = await self._store(name, "claim the next job", self.store.claim_next)
            if job is None:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), POLL_S)
                continue
            try:
                await self._run(name, job)
            except asyncio.CancelledError:
                raise
            except Exception:  # a bug here must not stop the queue
                log.exception("%s: job %s", name, job.id)
            finally:
                self._running.pop(job.id, None)
                self._cancel_wanted.discard(job.id)

    async def _run(self, name: str, job: JobRecord) -> None:
        cancel = self._running[job.id] = asyncio.Event()
        if job.id in self._cancel_wanted:
            cancel.set()
        retry_s = self.settings.storage_retry_s
        table = await self._store(name, f"read the table of job {job.id}", self.store.get_table,
                                  job.table_id)
        if table is None:  # cannot happen through the API (a table in use is not deleted)
            await self._store(name, f"fail job {job.id}", self.store.fail, job.id,
                              f"its table {job.table_id} is gone", give_up_after=retry_s)
            return
        path = str(self.store.table_path(job.table_id))

        async def progress(stage: str, fraction: float) -> None:
            try:  # progress is a courtesy: a write that fails is not worth a retry
                await asyncio.to_thread(self.store.set_progress, job.id, stage, fraction)
            except Exception as e:
                log.warning("job %s: progress not stored: %s", job.id, e)

        limit = self.settings.job_time_limit_s
        settle: tuple[Callable, tuple, str]
        try:
            outcome = await self.runner.run(
                tasks.fit_models, path, table.name, job.request,
                (table.summary or {}).get("input"),
                progress=progress, limit_s=limit, cancel=cancel,
            )
        except Cancelled as e:
            settle = (self.store.cancelled, (job.id, str(e)), "cancelled")
        except TimeLimitExceeded as e:
            settle = (self.store.fail, (job.id, f"{e} (BRDFFIT_JOB_TIME_LIMIT_S); not retried"),
                      "failed")
        except WorkerLost as e:
            status = await self._store(name, f"record the interruption of job {job.id}",
                                       self.store.retry_or_fail, job.id, str(e),
                                       self.max_attempts)
            log.warning("job %s: %s; now %s", job.id, e, status)
            return
        except Exception as e:  # the runner itself failed: say so on the job
            log.exception("job %s: runner error", job.id)
            settle = (self.store.fail, (job.id, f"internal error: {e!r}"), "failed")
        else:
            if outcome.ok:
                settle = (self.store.finish, (job.id, outcome.value, outcome.notes,
                                              outcome.seconds, outcome.measures_machine),
                          "done")
            else:
                if outcome.internal:
                    log.error("job %s failed:\n%s", job.id, outcome.traceback)
                settle = (self.store.fail, (job.id, outcome.reason), "failed")
        call, args, status = settle
        try:
            await self._store(name, f"store the outcome of job {job.id}", call, *args,
                              give_up_after=retry_s)
        except Exception as e:
            reason = (f"the job ended ({status}) but its outcome could not be stored for "
                      f"{retry_s:g} s (BRDFFIT_STORAGE_RETRY_S): {type(e).__name__}: {e}")
            try:
                await self._store(name, f"mark job {job.id} failed", self.store.fail, job.id,
                                  reason, give_up_after=retry_s)
            except Exception:
                # Still 'running' in the database: the next start settles it
                # (Store.recover). The loop goes on.
                log.error("job %s: %s; not even its failure could be stored", job.id, reason)
                self.problems.pop(name, None)
