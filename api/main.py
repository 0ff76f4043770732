"""Build the service: ``create_app(settings)`` -> a FastAPI app.

``create_app`` opens the store first, so a damaged database is refused
(``store.DatabaseRefused``: what is wrong and what to do) before the server
listens. The app's life (FastAPI lifespan): start the runner's workers, settle the
jobs a previous server left behind and start dispatching; on a clean stop, put
running jobs back in the queue and stop the workers.
"""

from __future__ import annotations

import logging
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from fastapi.routing import APIRoute

import brdffit
from api import errors
from api.jobs import JobQueue
from api.limits import RequestLimits
from api.routes import docs, exports, fits, health, materials, models, page, tables
from api.runner import AbstractRunner, make_runner
from api.settings import Settings
from api.store import ServerLock, Store
from brdffit.view.kinds import KINDS, SAMPLE_KINDS, SELECTION_KINDS

log = logging.getLogger("brdffit.api")

DESCRIPTION = f"""\
Fit analytic BRDF models to measured MERL tables.

1. `POST /v1/tables` with the `.binary` file as the body: a table id.
2. `POST /v1/fits` with `{{"table_id": ..., "models": "ggx"}}`: a job id (202).
3. `GET /v1/fits/{{id}}` until `status` is `done` (or `failed`, with a `reason`).
4. `GET /v1/fits/{{id}}/plots/{{kind}}.png`: {", ".join(KINDS)}; and for a sample list's fit,
   {", ".join(SAMPLE_KINDS)} (each sample, fitted against measured); and for auto's chosen
   fit, {", ".join(SELECTION_KINDS)} (every candidate, and why the chosen one).
5. `GET /v1/fits/{{id}}/exports/{{target}}`: the fit as a Mitsuba 3, glTF 2.0 or MaterialX
   material, with its error to the measured table under the renderer's own shading.

The same steps without a line of code: the web page at `/`.

Every error is JSON `{{"detail": "..."}}`. When the server sets `BRDFFIT_API_TOKEN`,
every route but `/healthz` needs `Authorization: Bearer <token>`.
"""


def create_app(settings: Settings | None = None, *,
               runner: AbstractRunner | None = None) -> FastAPI:
    """The service's app; ``runner`` replaces the one the settings would make."""
    settings = settings or Settings()
    store = Store(settings.data_dir, settings.database)  # raises DatabaseRefused

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        # before anything of the directory is touched: another server's running jobs
        # and uploads are its own (ServerLock; raises DataDirInUse)
        lock = ServerLock(settings.data_dir).acquire()
        try:
            store.clear_tmp()
            work = runner or make_runner(settings)
            work.start()
            queue = JobQueue(store, work, settings)
            app.state.settings, app.state.store = settings, store
            app.state.runner, app.state.queue = work, queue
            await queue.start()
            log.info("brdffit service: data in %s, %d worker(s)%s",
                     settings.data_dir.resolve(), settings.workers,
                     ", token required" if settings.api_token else "")
            try:
                yield
            finally:
                await queue.stop()
                work.close()
        finally:
            lock.release()

    app = FastAPI(
        title="brdffit",
        version=brdffit.__version__,
        description=DESCRIPTION,
        lifespan=lifespan,
        # Replaced by routes.docs, which sit behind the token like every route.
        openapi_url=None, docs_url=None, redoc_url=None,
        generate_unique_id_function=_operation_id,
    )
    errors.install(app)
    for module in (health, tables, materials, fits, exports, models, docs):
        app.include_router(module.router)
    app.include_router(docs.assets)
    # The page's choices before its files: /page/{name} would take the path otherwise.
    app.include_router(page.choices_router)
    app.include_router(page.router)
    app.add_middleware(RequestLimits, settings=settings)
    app.openapi = lambda: _openapi(app, settings)
    return app


def _operation_id(route: APIRoute) -> str:
    return route.name  # the handler's name: upload_table, get_fit, ...


def _openapi(app: FastAPI, settings: Settings) -> dict:
    """The document as this server behaves: the bearer scheme only when it has a
    token (the document is the client's contract, and schemathesis's)."""
    if app.openapi_schema is None:
        doc = get_openapi(title=app.title, version=app.version, description=app.description,
                          routes=app.routes)
        if settings.api_token is None:
            doc.get("components", {}).pop("securitySchemes", None)
            for operations in doc["paths"].values():
                for operation in operations.values():
                    operation.pop("security", None)
        app.openapi_schema = doc
    return app.openapi_schema
