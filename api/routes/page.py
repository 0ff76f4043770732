"""``/``: the service's web page (upload, fit, look, compare, export), and its files.

The page is plain HTML, one vanilla script and one stylesheet from
``api/static/page`` (no CDN, no build step: it works with no network). Its files
are public, like ``/docs``'s (a browser sends no token for them); everything the
page shows comes from the ``/v1`` routes, which it calls with the token the user
typed in when the server answered 401. ``/page/choices.json`` gives the page the
library's own lists (losses, scene presets, the defaults), so the form never
drifts from ``brdffit.fitting``.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, Depends, HTTPException, status
from fastapi.responses import FileResponse

from api.deps import require_token
from brdffit.fitting import options
from brdffit.fitting.scene import PRESETS
from brdffit.models import catalogue

FILES = Path(__file__).resolve().parent.parent / "static" / "page"
#: The files the page loads, and what they are: a fixed list, so no path from a
#: request reaches the disk.
MEDIA = {"index.html": "text/html; charset=utf-8", "page.js": "text/javascript; charset=utf-8",
         "page.css": "text/css; charset=utf-8", "icon.svg": "image/svg+xml"}
# The page changes with the server's version: a short cache, so an upgrade shows.
CACHE = {"Cache-Control": "no-cache"}

router = APIRouter(include_in_schema=False)
choices_router = APIRouter(include_in_schema=False, dependencies=[Depends(require_token)])


@router.get("/")
def page() -> FileResponse:
    return FileResponse(FILES / "index.html", media_type=MEDIA["index.html"], headers=CACHE)


@router.get("/favicon.ico")
def favicon() -> FileResponse:
    # browsers ask for /favicon.ico whatever the page links; an SVG answers them all
    return FileResponse(FILES / "icon.svg", media_type=MEDIA["icon.svg"], headers=CACHE)


@router.get("/page/{name}")
def page_file(name: str) -> FileResponse:
    if name not in MEDIA:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no page file {name!r}")
    return FileResponse(FILES / name, media_type=MEDIA[name], headers=CACHE)


@choices_router.get("/page/choices.json")
def choices() -> dict:
    """The form's lists, from the library: losses (default first), scene presets, the
    candidate sets auto takes by name, and the defaults the inputs show."""
    default_loss, loss = options.spec("loss")
    return {"losses": list(loss.choices), "default_loss": default_loss,
            "scene_presets": list(PRESETS), "auto": options.AUTO,
            "candidate_sets": [*catalogue.CANDIDATE_SETS, catalogue.DEFAULT_CANDIDATES],
            "defaults": {"samples": options.spec("samples")[0],
                         "starts": options.spec("starts")[0],
                         "max_steps": options.spec("max_steps")[0],
                         "tolerance": options.spec("tolerance", options.SelectionRule)[0],
                         "candidates": list(options.spec("candidates",
                                                         options.SelectionRule)[0])}}
