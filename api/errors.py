"""Every error leaves as JSON ``{"detail": "<one readable sentence>"}``.

Bad input is the client's fault and gets a 4xx naming the problem: the
library's own input errors (``MerlFormatError``, ``FitInputError``, an unknown
model) and request validation, whose list of pydantic errors is folded into one
line (and kept, structured, under ``errors``). Anything else is a bug: 500,
logged with its traceback, and the server carries on.
"""

from __future__ import annotations

import logging
import re
import sqlite3

from fastapi import FastAPI, Request, status
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from starlette.exceptions import HTTPException  # what FastAPI's body parsing raises

from brdffit.errors import BrdffitError
from brdffit.models import UnknownModelError

log = logging.getLogger("brdffit.api")


class BodyTimeout(Exception):
    """The client sent no part of its body for ``BRDFFIT_BODY_READ_TIMEOUT_S``."""


class ErrorMessage(BaseModel):
    """The body of every error response."""

    detail: str


#: For the routers' ``responses=``: what a client may get besides success.
ERROR_RESPONSES = {
    400: {"model": ErrorMessage, "description": "a body that cannot be parsed"},
    401: {"model": ErrorMessage, "description": "missing or wrong bearer token"},
    408: {"model": ErrorMessage, "description": "the body stalled (BRDFFIT_BODY_READ_TIMEOUT_S)"},
    413: {"model": ErrorMessage, "description": "body over the server's cap"},
    422: {"model": ErrorMessage, "description": "invalid request (the detail says what)"},
    503: {"model": ErrorMessage, "description": "the service's storage failed; try later"},
}


def _location(loc) -> str:
    parts = [str(p) for p in loc if p not in ("body",)] or ["body"]
    return ".".join(parts)


#: The longest message an error echoes: one quoting a 900,000-character model name was
#: a 1.8 MB answer (the name twice). Long enough for the library's own lists (an
#: unknown model's refusal names every model, ~600 characters: cut at 500 it left the
#: reader without ggx2); what a request sent is quoted shorter where it is quoted.
MAX_MESSAGE = 2000


def short(text: str) -> str:
    if len(text) <= MAX_MESSAGE:
        return text
    return f"{text[:MAX_MESSAGE]}... ({len(text):,} characters in all)"


def _message(error: dict) -> tuple[list[str], str]:
    """Where and what, in a reader's words: pydantic's "Value error, " prefix goes (the
    validator's own sentence is the message), and a body that is not JSON says so and
    where, instead of "12: JSON decode error"."""
    loc = [str(p) for p in error.get("loc", ())]
    msg = str(error.get("msg", ""))
    if error.get("type") == "json_invalid":
        why = (error.get("ctx") or {}).get("error")
        at = f" at character {loc[-1]}" if len(loc) > 1 else ""
        return ["body"], f"not valid JSON{at}" + (f": {why}" if why else "")
    if error.get("type") == "value_error":
        msg = msg.removeprefix("Value error, ")
    return [short(p) for p in loc], short(msg)


#: The last part of a location that names a union's member, not a field: pydantic reports
#: ``"models": null`` as "models.str: ...; models.list[str]: ...".
_UNION_MEMBER = re.compile(r"^(str|int|float|bool|none|list\[.*\]|dict\[.*\])$")


def _unions_merged(errors: list[dict]) -> list[dict]:
    """One message per field for a value that fits none of a union's members: "models:
    Input should be a valid string, or Input should be a valid list"."""
    merged: dict[tuple, dict] = {}
    for e in errors:
        loc = e["loc"]
        if len(loc) > 1 and _UNION_MEMBER.match(loc[-1]):
            key = tuple(loc[:-1])
            if key in merged:
                merged[key]["msg"] += f", or {e['msg']}"
                continue
            e = {"loc": list(key), "msg": e["msg"]}
        else:
            key = (id(e),)
        merged[key] = e
    return list(merged.values())


async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
    errors = _unions_merged([dict(zip(("loc", "msg"), _message(e), strict=True))
                             for e in exc.errors()])
    detail = "; ".join(f"{_location(e['loc'])}: {e['msg']}" for e in errors) or "invalid request"
    return JSONResponse({"detail": detail, "errors": errors},
                        status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)


async def _http_error(request: Request, exc: HTTPException):
    """FastAPI's own errors as it sends them, but for a JSON body that is not UTF-8,
    nested too deep for the parser, or holding an integer of more than 4,300 digits:
    it answered each with a bare 400 "There was an error parsing the body"; each is a
    body that is not valid JSON (RFC 8259: JSON is UTF-8) or a request no option
    takes, said as every other such body is (422, with ``errors``)."""
    cause = exc.__cause__
    msg = None
    if exc.status_code == 400 and isinstance(cause, UnicodeDecodeError):
        msg = (f"not valid JSON: not UTF-8 (byte 0x{cause.object[cause.start]:02x} at "
               f"byte {cause.start}); send JSON encoded as UTF-8")
    elif exc.status_code == 400 and isinstance(cause, RecursionError):
        msg = "JSON nested deeper than the parser follows; no request is nested so deep"
    elif exc.status_code == 400 and isinstance(cause, ValueError) and "digits" in str(cause):
        # Python's limit on converting a long integer (4,300 digits), hit while parsing
        msg = "a number of more than 4,300 digits; no option takes one"
    if msg is not None:
        return JSONResponse({"detail": f"body: {msg}", "errors": [{"loc": ["body"],
                                                                   "msg": msg}]},
                            status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)
    return await http_exception_handler(request, exc)


async def _input_error(request: Request, exc: Exception) -> JSONResponse:
    return JSONResponse({"detail": short(str(exc))},
                        status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)


def internal_error_body(scope, exc: Exception) -> dict:
    """Log a bug with its traceback; the body of its 500 (``api.limits`` sends it)."""
    log.error("%s %s failed", scope.get("method"), scope.get("path"), exc_info=exc)
    return {"detail": f"internal server error ({type(exc).__name__})"}


async def _storage_error(request: Request, exc: Exception) -> JSONResponse:
    # Not the request's fault, and not a bug: the disk or the database under the
    # service failed (read-only, full, gone). Nothing was accepted; try later.
    log.error("%s %s: storage error: %s", request.method, request.url.path, exc)
    return JSONResponse({"detail": f"the service's storage failed ({type(exc).__name__}: "
                                   f"{exc}); nothing was stored, try again later"},
                        status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
                        headers={"Retry-After": "10"})


async def _body_timeout(request: Request, exc: Exception) -> JSONResponse:
    return JSONResponse({"detail": str(exc)}, status_code=status.HTTP_408_REQUEST_TIMEOUT,
                        headers={"Connection": "close"})


def install(app: FastAPI) -> None:

    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(HTTPException, _http_error)
    app.add_exception_handler(BrdffitError, _input_error)
    app.add_exception_handler(UnknownModelError, _input_error)
    app.add_exception_handler(sqlite3.Error, _storage_error)
    app.add_exception_handler(BodyTimeout, _body_timeout)
    # Anything else is answered by api.limits.RequestLimits (internal_error_body).
