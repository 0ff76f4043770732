"""``GET /v1/fits/{job_id}/exports/{target}``: a finished fit as a renderer's material.

The response is ``brdffit.export.Export.to_dict()`` (schema ``brdffit.export/1``,
docs/exports.md): the material, its files, the warnings of every clamp and
approximation, and the fidelity. A conversion that is not exact refits the target's
model to the fit (seconds of JAX), so it runs in a worker process like a fit.
"""

from __future__ import annotations

import logging
from enum import Enum
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, HTTPException, Query, status
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, ConfigDict, Field

from api import tasks
from api.deps import RunnerDep, StoreDep, require_token
from api.errors import ERROR_RESPONSES, ErrorMessage
from api.routes.fits import (
    FitModel,
    JobId,
    finished_fit,
    kept_for_the_job,
    worker_unavailable,
)
from api.runner import TimeLimitExceeded, WorkerLost
from brdffit.export import SCHEMA, TARGETS

log = logging.getLogger("brdffit.api")

#: The longest an export may run in its worker (a Mitsuba export's refit: ~12 s): past
#: it the worker is replaced and the request answered 503, rather than holding the
#: worker, and the fits queued behind it, for as long as it runs.
EXPORT_LIMIT_S = 300.0

router = APIRouter(prefix="/v1/fits", tags=["exports"], dependencies=[Depends(require_token)],
                   responses=ERROR_RESPONSES)

ExportTarget = Enum("ExportTarget", {t: t for t in TARGETS}, type=str)  # type: ignore[misc]


class ExportOut(BaseModel):
    """``brdffit.export.Export.to_dict()`` (docs/exports.md, schema ``brdffit.export/2``)."""

    model_config = ConfigDict(populate_by_name=True)

    schema_: str = Field(SCHEMA, alias="schema", description="the export schema's version")
    target: str = Field(description="mitsuba, gltf or materialx")
    source_model: str = Field(description="the fitted model")
    media_type: str = Field(description="of the material document")
    material: dict | str = Field(description="Mitsuba load_dict dictionary, glTF JSON "
                                             "document, or MaterialX XML text")
    files: dict[str, str] = Field(description="file name -> text, ready to save")
    fidelity: dict = Field(description="exact, target_model, renderer_model, log_rmse_to_fit, "
                                       "fit_log_rmse, log_rmse_to_table, sphere_colour, "
                                       "render_psnr_db, "
                                       "viewers (glTF), albedo_max, albedo_max_theta_deg")
    target_params: dict = Field(description="the target model's parameters")
    warnings: list[str] = Field(description="every clamp and approximation")
    table: str | None = None
    variants: dict | None = Field(None, description="Mitsuba: the rgb and spectral variants' "
                                                    "dictionaries and which variants each is for")


@router.get(
    "/{job_id}/exports/{target}",
    summary="A finished fit as a Mitsuba 3, glTF 2.0 or MaterialX material",
    responses={
        404: {"model": ErrorMessage, "description": "no such job, or no such model in it"},
        409: {"model": ErrorMessage, "description": "the job is not done"},
        422: {"model": ErrorMessage, "description": "this fit cannot be exported"},
        503: {"model": ErrorMessage, "description": "the worker died; try again"},
    },
)
async def get_export(
    job_id: JobId,
    target: ExportTarget,
    store: StoreDep,
    runner: RunnerDep,
    model: FitModel = None,
    target_model: Annotated[str | None, Query(
        max_length=64,  # a model's name; a 5,000-character one was echoed whole in the 422
        description="which of the renderer's models the file carries: "
                    + "; ".join(f"{t}: {', '.join(m.SHADED_AS)}" for t, m in TARGETS.items())
                    + " (default: the first)")] = None,
    viewer: Annotated[Literal["spec", "threejs", "blender"], Query(
        description="glTF: fit the factors for the spec's definition (default) or for the "
                    "way three.js or Blender (Cycles) shades them")] = "spec",
) -> ExportOut:
    job, result = await finished_fit(store, job_id, model, "exports")
    # made once, then served from the data dir as a plot is (each GET made it again in
    # a worker, 5-15 s, queued before later fits); only for a renderer's model the
    # target has (the name is part of the file's)
    kept = (store.export_path(job_id, result["model"], target.value, target_model, viewer)
            if target_model is None or target_model in TARGETS[target.value].SHADED_AS
            else None)
    if kept is not None and kept.exists():
        return ExportOut.model_validate_json(await run_in_threadpool(kept.read_bytes))
    # the job's table, for the export's error to the measurement (a deleted one: said)
    path = store.table_path(job.table_id)

    async def exported(table: str | None):
        try:
            return await runner.run(tasks.export_fit, result, target.value, table,
                                    target_model, viewer, limit_s=EXPORT_LIMIT_S)
        except (WorkerLost, TimeLimitExceeded) as e:
            raise worker_unavailable(e, f"the {target.value} export") from None

    table = str(path) if path.exists() else None
    outcome = await exported(table)
    if not outcome.ok and table is not None and not path.exists():
        # the table deleted while the export waited for a worker: a 422 that quoted the
        # data dir's path of the file. Its job gone too (with_fits): 404; else the export
        # is made as for a table deleted before (its fidelity to the table not measured)
        if await run_in_threadpool(store.get_job, job_id) is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND,
                                f"no fit job {job_id}: deleted while it was exported")
        outcome = await exported(None)
    if not outcome.ok:
        if not outcome.internal:  # this fit cannot be exported so: the request's answer
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_ENTITY, outcome.reason)
        log.error("export %s of job %s failed:\n%s", target.value, job_id, outcome.traceback)
        raise HTTPException(status.HTTP_500_INTERNAL_SERVER_ERROR,
                            f"the {target.value} export failed: {outcome.reason}")
    out = ExportOut.model_validate(outcome.value)
    if kept is not None and table is not None and path.exists():
        # kept where it was judged against the job's table: one made without it (the
        # table's file gone) would stay without that figure if the file came back
        await kept_for_the_job(store, job_id, kept, out.model_dump_json(by_alias=True).encode())
    return out
