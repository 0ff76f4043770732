"""The OpenAPI document and its browsable page, behind the token like the rest.

FastAPI's own ``/openapi.json`` and ``/docs`` routes take no dependencies, so
the app switches them off and these take their place.
"""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse, JSONResponse

from api.deps import require_token

router = APIRouter(dependencies=[Depends(require_token)], include_in_schema=False)


@router.get("/openapi.json")
def openapi(request: Request) -> JSONResponse:
    return JSONResponse(request.app.openapi())


@router.get("/docs")
def docs(request: Request) -> HTMLResponse:
    return get_swagger_ui_html(openapi_url="/openapi.json", title=f"{request.app.title} docs")
