"""What the routes receive: settings, store, job queue, runner, and the token check."""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from fastapi.security.utils import get_authorization_scheme_param

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


def token_refusal(settings: Settings, token: str | None) -> HTTPException | None:
    """The 401 for a request whose bearer token is ``token`` (None: it sent none), or
    None where it may pass (the right token, or a server without one). One check for
    the routes (:func:`require_token`) and for a body's first reader, the request
    limits (``api.limits``): a malformed body of a request without the token was
    answered 422 before its 401."""
    if settings.api_token is None:
        return None
    if token is None:
        return HTTPException(status.HTTP_401_UNAUTHORIZED,
                             "this server needs 'Authorization: Bearer <token>'",
                             headers={"WWW-Authenticate": "Bearer"})
    if not secrets.compare_digest(token.encode(), settings.api_token.get_secret_value().encode()):
        return HTTPException(status.HTTP_401_UNAUTHORIZED, "wrong bearer token",
                             headers={"WWW-Authenticate": 'Bearer error="invalid_token"'})
    return None


def bearer_token(authorization: str | None) -> str | None:
    """The token of an ``Authorization: Bearer <token>`` header, as FastAPI's
    ``HTTPBearer`` reads it (``get_authorization_scheme_param``: the scheme in any
    case, the token stripped), else None."""
    scheme, token = get_authorization_scheme_param(authorization)
    return token if authorization and scheme.lower() == "bearer" and token else None


def require_token(
    settings: SettingsDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> None:
    """401 unless the request carries the server's token (no-op without one)."""
    refusal = token_refusal(settings, None if credentials is None else credentials.credentials)
    if refusal is not None:
        raise refusal
