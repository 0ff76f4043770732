"""``/healthz``: can the service make progress now? (No token needed.)

Ready means: the database takes a write, the data dir has room
(``BRDFFIT_MIN_FREE_MIB``), and every job dispatch loop is running without a
storage problem. Otherwise the answer is 503 and ``problems`` says what is wrong;
it turns back to 200 by itself once the cause is gone (a load balancer or Docker's
health check then sends work again).
"""

from __future__ import annotations

import shutil

from fastapi import APIRouter, Response, status
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from api.deps import QueueDep, SettingsDep, StoreDep
from brdffit import __version__

router = APIRouter(tags=["health"])

MiB = 1024 * 1024


class Health(BaseModel):
    status: str = Field(description="ok, or unavailable (the answer is then a 503)")
    version: str
    problems: list[str] = Field(description="why the service cannot make progress now")
    jobs: dict[str, int] | None = Field(None, description="jobs per status (null: unreadable)")


def _check(store, settings, queue) -> tuple[list[str], dict | None]:
    problems, jobs = [], None
    try:
        store.probe()
        jobs = store.counts()
    except Exception as e:
        problems.append(f"the job database takes no write: {type(e).__name__}: {e}")
    try:
        free = shutil.disk_usage(store.data_dir).free
        if free < settings.min_free_mib * MiB:
            problems.append(f"{free / MiB:,.0f} MiB free in {store.data_dir}, under "
                            f"{settings.min_free_mib:,} MiB (BRDFFIT_MIN_FREE_MIB)")
    except OSError as e:
        problems.append(f"the data dir is unreadable: {e}")
    if not queue.alive:
        problems.append("a job dispatch loop has stopped (a bug: see the server log)")
    problems += [f"{name}: {p}" for name, p in sorted(queue.problems.items())]
    return problems, jobs


@router.get("/healthz", summary="Readiness: 200 when the service can make progress",
            responses={503: {"model": Health, "description": "it cannot now: see problems"}})
async def healthz(response: Response, store: StoreDep, settings: SettingsDep,
                  queue: QueueDep) -> Health:
    problems, jobs = await run_in_threadpool(_check, store, settings, queue)
    if problems:
        response.status_code = status.HTTP_503_SERVICE_UNAVAILABLE
    return Health(status="unavailable" if problems else "ok", version=__version__,
                  problems=problems, jobs=jobs)
