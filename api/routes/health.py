"""``/healthz``: is the server up and its database reachable? (No token needed.)"""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel

from api.deps import StoreDep
from brdffit import __version__

router = APIRouter(tags=["health"])


class Health(BaseModel):
    status: str
    version: str


@router.get("/healthz", summary="Liveness and database check")
async def healthz(store: StoreDep) -> Health:
    await run_in_threadpool(store.counts)  # raises (-> 500) if the database is gone
    return Health(status="ok", version=__version__)
