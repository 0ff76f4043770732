"""Request bounds, applied before a route sees the request (an ASGI middleware).

- A request to a ``/v1`` route with a body and without the server's token is a 401
  before its body is read (``api.deps.token_refusal``, the routes' own check).
- A body that stalls (sends nothing for ``BRDFFIT_BODY_READ_TIMEOUT_S``) is a 408:
  a slow or stuck client does not hold a connection and a temp file forever.
- A body other than a table upload is read here, up to ``BRDFFIT_MAX_JSON_BYTES``
  (413 past it), then handed to the route: no JSON body is unbounded. The upload
  route streams its body itself (``routes.tables``), against its own cap.
- An exception no handler took becomes the JSON 500 of :mod:`api.errors` here,
  inside the server: answered like any error, the keep-alive connection survives
  (Starlette's outermost error middleware answers and then drops it).
"""

from __future__ import annotations

import asyncio
import json

from api.deps import bearer_token, token_refusal
from api.errors import BodyTimeout, internal_error_body
from api.settings import Settings

#: Routes that stream their body themselves: (method, path).
STREAMED = {("POST", "/v1/tables")}


class RequestLimits:
    def __init__(self, app, settings: Settings):
        self.app = app
        self.settings = settings

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        started = False

        async def tracked_send(message):
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        timeout = self.settings.body_read_timeout_s

        async def timed_receive():
            try:
                return await asyncio.wait_for(receive(), timeout)
            except TimeoutError:
                raise BodyTimeout(f"no part of the request body arrived for {timeout:g} s "
                                  "(BRDFFIT_BODY_READ_TIMEOUT_S)") from None

        app_receive = timed_receive
        has_body = _may_have_body(scope)
        if has_body and scope["path"].startswith("/v1/"):
            # every /v1 route needs the token: refused before a byte of its body is read
            # (a malformed body without it was answered 422, and 1 MiB of it read)
            refusal = token_refusal(self.settings, bearer_token(_header(scope, b"authorization")))
            if refusal is not None:
                return await _answer(send, refusal.status_code, refusal.detail,
                                     refusal.headers)
        if has_body and (scope["method"], scope["path"]) not in STREAMED:
            cap = self.settings.max_json_bytes
            try:
                body = await _read_body(timed_receive, cap)
            except BodyTimeout as e:
                return await _answer(send, 408, str(e))
            except _TooLarge:
                return await _answer(send, 413, f"request body larger than {cap:,} bytes "
                                                "(BRDFFIT_MAX_JSON_BYTES)")
            if body is None:  # the client left
                return
            app_receive = _replay(body, receive)
        try:
            await self.app(scope, app_receive, tracked_send)
        except Exception as exc:
            if started:
                raise  # half a response is out: only dropping the connection is honest
            await _answer(send, 500, internal_error_body(scope, exc)["detail"])


class _TooLarge(Exception):
    pass


def _may_have_body(scope) -> bool:
    headers = dict(scope["headers"])
    return b"content-length" in headers or b"transfer-encoding" in headers


async def _read_body(receive, cap: int) -> bytes | None:
    chunks, size = [], 0
    while True:
        message = await receive()
        if message["type"] == "http.disconnect":
            return None
        chunk = message.get("body", b"")
        size += len(chunk)
        if size > cap:
            raise _TooLarge
        chunks.append(chunk)
        if not message.get("more_body", False):
            return b"".join(chunks)


def _replay(body: bytes, receive):
    sent = False

    async def replay():
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()  # after the body: the disconnect, when it comes

    return replay


def _header(scope, name: bytes) -> str | None:
    """The first ``name`` header, as Starlette's ``Headers.get`` reads it (the routes'
    token check reads it so; ``dict`` kept the last of two)."""
    value = next((v for k, v in scope["headers"] if k == name), None)
    return None if value is None else value.decode("latin-1")


async def _answer(send, status: int, detail: str, headers: dict | None = None) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode()),
                            *((k.lower().encode(), v.encode("latin-1"))
                              for k, v in (headers or {}).items())]})
    await send({"type": "http.response.body", "body": body})
