"""``api.limits.RequestLimits`` in process: a bug's 500 is answered by the app (so
uvicorn keeps the connection), and a JSON body is capped before a route reads it."""

from __future__ import annotations

import asyncio

import httpx
import pytest
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.routing import Route

from api.limits import RequestLimits
from api.settings import Settings

pytestmark = pytest.mark.unit


async def _broken(request: Request):
    raise RuntimeError("a bug")


async def _echo(request: Request):
    return JSONResponse({"n": len(await request.body())})


def _call(method: str, path: str, **kw) -> httpx.Response:
    # Where api.main puts it: inside Starlette's outermost error middleware, which
    # would answer a plain-text 500 and then re-raise (and uvicorn drop the connection).
    limited = Starlette(
        routes=[Route("/broken", _broken), Route("/echo", _echo, methods=["POST"])],
        middleware=[Middleware(RequestLimits, settings=Settings(max_json_bytes=1024))],
    )

    async def go():
        # An exception that escaped the app would raise here (raise_app_exceptions).
        transport = httpx.ASGITransport(app=limited)
        async with httpx.AsyncClient(transport=transport, base_url="http://t") as client:
            return await client.request(method, path, **kw)

    return asyncio.run(go())


def test_a_bug_is_a_json_500_answered_inside_the_app():
    r = _call("GET", "/broken")
    assert r.status_code == 500
    assert r.json() == {"detail": "internal server error (RuntimeError)"}


def test_a_json_body_over_the_cap_is_a_413_before_the_route():
    assert _call("POST", "/echo", content=b"x" * 1024).json() == {"n": 1024}
    r = _call("POST", "/echo", content=b"x" * 1025)
    assert r.status_code == 413 and "BRDFFIT_MAX_JSON_BYTES" in r.json()["detail"]
