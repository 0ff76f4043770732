"""Every error leaves as JSON ``{"detail": "<one readable sentence>"}``.

Bad input is the client's fault and gets a 4xx naming the problem: the
library's own input errors (``MerlFormatError``, ``FitInputError``, an unknown
model) and request validation, whose list of pydantic errors is folded into one
line (and kept, structured, under ``errors``). Anything else is a bug: 500,
logged with its traceback, and the server carries on.
"""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel

from brdffit.errors import BrdffitError
from brdffit.models import UnknownModelError

log = logging.getLogger("brdffit.api")


class ErrorMessage(BaseModel):
    """The body of every error response."""

    detail: str


#: For the routers' ``responses=``: what a client may get besides success.
ERROR_RESPONSES = {
    400: {"model": ErrorMessage, "description": "a body that cannot be parsed"},
    401: {"model": ErrorMessage, "description": "missing or wrong bearer token"},
    422: {"model": ErrorMessage, "description": "invalid request (the detail says what)"},
}


def _location(loc) -> str:
    parts = [str(p) for p in loc if p not in ("body",)] or ["body"]
    return ".".join(parts)


async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
    errors = [{"loc": [str(p) for p in e.get("loc", ())], "msg": str(e.get("msg", ""))}
              for e in exc.errors()]
    detail = "; ".join(f"{_location(e['loc'])}: {e['msg']}" for e in errors) or "invalid request"
    return JSONResponse({"detail": detail, "errors": errors},
                        status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)


async def _input_error(request: Request, exc: Exception) -> JSONResponse:
    return JSONResponse({"detail": str(exc)}, status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)


async def _internal_error(request: Request, exc: Exception) -> JSONResponse:
    log.error("%s %s failed", request.method, request.url.path, exc_info=exc)
    return JSONResponse({"detail": f"internal server error ({type(exc).__name__})"},
                        status_code=status.HTTP_500_INTERNAL_SERVER_ERROR)


def install(app: FastAPI) -> None:
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(BrdffitError, _input_error)
    app.add_exception_handler(UnknownModelError, _input_error)
    app.add_exception_handler(Exception, _internal_error)
