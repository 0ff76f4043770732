"""What the routes receive: settings, store, job queue, runner, and the token check."""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from api.jobs import JobQueue
from api.runner import AbstractRunner
from api.settings import Settings
from api.store import Store


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_queue(request: Request) -> JobQueue:
    return request.app.state.queue


def get_runner(request: Request) -> AbstractRunner:
    return request.app.state.runner


SettingsDep = Annotated[Settings, Depends(get_settings)]
StoreDep = Annotated[Store, Depends(get_store)]
QueueDep = Annotated[JobQueue, Depends(get_queue)]
RunnerDep = Annotated[AbstractRunner, Depends(get_runner)]

_bearer = HTTPBearer(auto_error=False, description="BRDFFIT_API_TOKEN, when the server sets one")


def require_token(
    settings: SettingsDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> None:
    """401 unless the request carries the server's token (no-op without one)."""
    if settings.api_token is None:
        return
    expected = settings.api_token.get_secret_value()
    if credentials is None:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED,
                            "this server needs 'Authorization: Bearer <token>'",
                            headers={"WWW-Authenticate": "Bearer"})
    if not secrets.compare_digest(credentials.credentials.encode(), expected.encode()):
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "wrong bearer token",
                            headers={"WWW-Authenticate": 'Bearer error="invalid_token"'})
