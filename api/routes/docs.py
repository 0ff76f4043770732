"""The OpenAPI document and its browsable page, behind the token like the rest.

FastAPI's own ``/openapi.json`` and ``/docs`` routes take no dependencies, so
the app switches them off and these take their place. The page's Swagger UI
files are served from ``api/static/swagger-ui`` (vendored, see its README), not
a CDN: ``/docs`` works with no network. They are public files, served without
the token (a browser does not send one for a script or a stylesheet).
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, Depends, HTTPException, Request, status
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse

from api.deps import require_token

ASSETS = Path(__file__).resolve().parent.parent / "static" / "swagger-ui"
#: The files the page loads, and what they are.
MEDIA = {"swagger-ui-bundle.js": "text/javascript", "swagger-ui.css": "text/css",
         "favicon-32x32.png": "image/png"}
ASSET_URL = "/docs/assets"

router = APIRouter(dependencies=[Depends(require_token)], include_in_schema=False)
assets = APIRouter(include_in_schema=False)


@router.get("/openapi.json")
def openapi(request: Request) -> JSONResponse:
    return JSONResponse(request.app.openapi())


@router.get("/docs")
def docs(request: Request) -> HTMLResponse:
    return get_swagger_ui_html(
        openapi_url="/openapi.json", title=f"{request.app.title} docs",
        swagger_js_url=f"{ASSET_URL}/swagger-ui-bundle.js",
        swagger_css_url=f"{ASSET_URL}/swagger-ui.css",
        swagger_favicon_url=f"{ASSET_URL}/favicon-32x32.png",
        # No badge from the online validator: nothing on the page leaves this server.
        swagger_ui_parameters={"validatorUrl": None},
    )


@assets.get(ASSET_URL + "/{name}")
def asset(name: str) -> FileResponse:
    if name not in MEDIA:  # a fixed list: no path from the request reaches the disk
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no docs asset {name!r}")
    return FileResponse(ASSETS / name, media_type=MEDIA[name],
                        headers={"Cache-Control": "public, max-age=86400"})
