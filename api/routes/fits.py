"""``/v1/fits``: queue a fit of a table, follow it, fetch its result and plots.

A request is checked completely before it is queued (table known, models known,
every option in range): a job that fails later fails for what only the fit can
find out (say, too few usable bins), and says so in ``reason``.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import os
import shutil
import typing
from datetime import UTC, datetime
from enum import Enum
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, HTTPException, Path, Query, Request, Response, status
from fastapi.concurrency import run_in_threadpool
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictFloat,
    StrictInt,
    create_model,
    field_validator,
    model_validator,
)

from api import tasks
from api.deps import QueueDep, RunnerDep, SettingsDep, StoreDep, require_token
from api.errors import ERROR_RESPONSES, ErrorMessage, short
from api.runner import TimeLimitExceeded, WorkerLost
from api.services import fits
from api.store import STATUSES, JobRecord, Store
from brdffit import models
from brdffit.errors import FitInputError
from brdffit.fitting import options
from brdffit.fitting.options import names
from brdffit.fitting.result import SCHEMA, FitResult
from brdffit.fitting.scene import SceneError
from brdffit.request import REQUEST_SCHEMA, FitRequest, legacy_request
from brdffit.selection import chosen_result
from brdffit.view.kinds import (
    EXPOSURE_EV_RANGE,
    KINDS,
    SAMPLE_KINDS,
    SELECTION_KINDS,
    exposure_refused,
)

log = logging.getLogger("brdffit.api")

#: The longest a plot may render in its worker (a second or two; a report of every
#: candidate, several): past it the worker is replaced and the request answered 503.
PLOT_LIMIT_S = 300.0

router = APIRouter(prefix="/v1/fits", tags=["fits"], dependencies=[Depends(require_token)],
                   responses=ERROR_RESPONSES)

JobId = Annotated[str, Path(pattern=r"^[0-9a-f]{32}$", description="the id POST /v1/fits gave")]
#: ``?model=``: which model's fit of a job a plot or an export is of.
FitModel = Annotated[str | None, Query(max_length=64,
                                       description="which model's fit (default: the best)")]

PlotKind = Enum("PlotKind", {k: k for k in (*KINDS, *SAMPLE_KINDS, *SELECTION_KINDS)},  # type: ignore[misc]
                type=str)


def _contract_field(name: str, of: type = options.FitOptions):
    """``(annotation, Field)`` of one field of ``brdffit.fitting.options.FitOptions`` (or
    ``SelectionRule``): the request schema's type, default, bounds and description are
    the library's."""
    default, opt = options.spec(name, of)
    # strict, as the library is: "yes" is no bool, true no count, 1e4 no integer
    annotation = (Literal[opt.choices] if opt.choices is not None
                  else StrictBool if opt.kind is bool
                  else StrictInt if opt.kind is int
                  else StrictFloat if opt.kind is float
                  else list[str] if opt.kind is tuple else opt.kind)
    if opt.none is not None or opt.kind is tuple:
        annotation = annotation | None
    if opt.kind is tuple:  # a list of names: null (or absent) for the library's default
        default, description = None, opt.doc + "; null for the default"
    else:
        description = opt.doc + (f"; null for {opt.none}" if opt.none is not None else "")
    # a NaN or 1e999 (inf) is refused as not finite, not as "less than or equal to 10"
    finite = {"allow_inf_nan": False} if opt.kind is float else {}
    return annotation, Field(default, ge=opt.least, gt=opt.above, le=opt.most,
                             description=description, **finite,
                             **({"max_length": 32} if opt.kind is tuple else {}))


# The request body is brdffit.request.FitRequest.to_dict() (docs/service.md) and a
# table id: each part generated from the library's own declarations, so that the
# service cannot drift from the library (and the library has the last word, below).
FitOptions = create_model(
    "FitOptions", __config__=ConfigDict(extra="forbid"),
    __doc__="``brdffit.fitting.options.FitOptions``: the fit's options, with the library's "
            "names, defaults and ranges (as `brdffit fit`'s flags)",
    **{name: _contract_field(name) for name in options.names()},
)
SelectionRule = create_model(
    "SelectionRule", __config__=ConfigDict(extra="forbid"),
    __doc__="``brdffit.fitting.options.SelectionRule``: how model 'auto' chooses "
            "(docs/selection.md); only with model 'auto'",
    **{name: _contract_field(name, options.SelectionRule)
       for name in options.names(options.SelectionRule)},
)


#: The most direction pairs a request's scene may make: about as many as a JSON body of
#: BRDFFIT_MAX_JSON_BYTES (1 MiB) carries as ``pairs``. ``lights`` x ``views`` is their
#: product, counted before the scene is made: 1,000 of each, a 53 KB body, took 35 s to
#: accept and made a job record of 1M pairs (124 MB of JSON, every listing 136 MB).
MAX_REQUEST_PAIRS = 20_000


def _scene_pairs(scene: dict) -> int:
    def count(key) -> int:
        v = scene.get(key)
        return len(v) if isinstance(v, list) else 0

    return count("pairs") + count("lights") * count("views")


class RequestForm(BaseModel):
    """``brdffit.request.FitRequest.to_dict()``: the one form of a fit request, its
    shapes and bounds (a job's stored request, as served: checked by the library when
    it was posted, :class:`RequestBody`, and not again on every read, which cost 0.8 s
    of the server's CPU per GET of a job whose scene held 19,881 pairs)."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    schema_: Literal[REQUEST_SCHEMA] = Field(  # type: ignore[valid-type]
        REQUEST_SCHEMA, alias="schema", description="the request schema's version")
    models: str | list[str] = Field(
        options.DEFAULT_MODEL,
        description="a model name (GET /v1/models) or a list of them: each is fitted, the "
        "best (lowest log_rmse) is the job's `result`; or 'auto': the rule's candidates are "
        "fitted and the cheapest good enough is the `result`, its `selection` says why")
    options: FitOptions = FitOptions()
    scene: dict | None = Field(
        None, description="only the directions a scene uses count (docs/selection.md): "
        "preset, max_theta_i, max_theta_o, pairs, lights, views, spread, name")
    rule: SelectionRule | None = Field(
        None, description="model 'auto' only: tolerance, budget, candidates, mono_ks "
        "(null: the default rule)")

    @field_validator("models")
    @classmethod
    def _at_most_every_model(cls, v: str | list[str]) -> str | list[str]:
        if isinstance(v, list) and len(v) > len(models.names()):
            raise ValueError(f"at most {len(models.names())} models per job")
        return v

    @field_validator("scene")
    @classmethod
    def _no_server_paths(cls, v: dict | None) -> dict | None:
        if v is not None and "pairs_file" in v:  # a path on the server: not the client's
            raise ValueError("scene: pairs_file is not accepted here; send pairs")
        if v is not None and (n := _scene_pairs(v)) > MAX_REQUEST_PAIRS:
            raise ValueError(
                f"scene: it makes {n:,} direction pairs (pairs, and every light with every "
                f"view): a request's scene holds at most {MAX_REQUEST_PAIRS:,}; a scene is "
                "binned onto the table's bins, so a subset drawn at random weights the fit "
                "alike (or fit it with the CLI, whose scene files may hold more)")
        return v

    def request_dict(self) -> dict:
        """The body as ``FitRequest.to_dict()`` has it (what the job stores)."""
        return self.model_dump(by_alias=True, exclude={"table_id"})


class RequestBody(RequestForm):
    """A fit request as posted: its shapes (:class:`RequestForm`), then the library's
    own check."""

    @model_validator(mode="after")
    def _valid_for_the_library(self) -> RequestBody:
        # Pydantic has checked the shapes and bounds it was given; the library has the
        # last word (model names, auto beside others, a rule with a fixed model, scenes).
        try:
            request = FitRequest.from_dict(self.request_dict())
            if request.scene is not None:
                request.scene.bin_weight()  # a scene that names no direction, say
        except (FitInputError, SceneError, models.UnknownModelError) as e:
            raise ValueError(str(e)) from None
        return self


class FitJobRequest(RequestBody):
    """``POST /v1/fits``: a table and the request (``brdffit.request.FitRequest.to_dict()``
    with ``table_id``). The form before ``brdffit.request/1`` (``model`` and one flat
    ``options`` holding scene, candidates, mono_ks, tolerance, budget) is still read,
    rearranged (``brdffit.request.legacy_request``)."""

    table_id: str = Field(pattern=r"^[0-9a-f]{64}$", description="from POST /v1/tables")

    @model_validator(mode="before")
    @classmethod
    def _from_the_earlier_form(cls, data):
        legacy_keys = set(names(options.SelectionRule)) | {"scene"}
        if isinstance(data, dict) and ("model" in data or (
                isinstance(data.get("options"), dict) and legacy_keys & set(data["options"]))):
            if "models" in data or "rule" in data:
                raise ValueError("give `models` (and `rule`), or the earlier `model` with "
                                 "flat options, not both")
            request = legacy_request(data.get("model", options.DEFAULT_MODEL),
                                     data.get("options", {}))
            # the rest of the body is kept, to be read or refused as any body's is: a
            # top-level scene beside `model` was dropped without a word (the fit weighed
            # the whole table), as was any key this form does not have
            rest = {k: v for k, v in data.items() if k not in ("table_id", "model", "options")}
            if rest.get("scene") is not None and request.get("scene") is not None:
                raise ValueError("a scene at the top level and another in `options`: give one")
            data = {"table_id": data.get("table_id"), **request,
                    **{k: v for k, v in rest.items() if k != "scene" or v is not None}}
        return data


def _result_field(f: dataclasses.Field, hints: dict):
    """``(annotation, Field)`` of one ``FitResult`` field. JSON is strict: a metric a
    fit could not measure (NaN) is null, so every float may be null."""
    annotation = hints[f.name]
    if f.name in ("error", "full_table_error"):
        annotation = dict[str, float | None] | (None if f.name == "full_table_error"
                                                 else dict[str, float | None])
    required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    return annotation, Field(... if required else f.default,
                             description=FitResult.described().get(f.name))


# ``FitResult.to_dict()``, the result schema (docs/results.md), derived from the class: a
# key added to FitResult is served without another declaration here. Extra keys are
# kept, not dropped: a job stored by an older version is served as it was stored.
FitResultOut = create_model(
    "FitResultOut", __config__=ConfigDict(extra="allow", populate_by_name=True),
    __doc__="``FitResult.to_dict()``, the result schema (docs/results.md): the JSON of "
            "``brdffit fit --json`` (NaN as null).",
    schema_=(str, Field(SCHEMA, alias="schema", description="the result schema's version")),
    **{f.name: _result_field(f, typing.get_type_hints(FitResult))
       for f in dataclasses.fields(FitResult)},
)


class Progress(BaseModel):
    stage: str = Field(description="what the job is doing, e.g. 'fitting ggx (2 of 3)'")
    fraction: float = Field(ge=0, le=1, description="share of the job's models finished")


class JobOut(BaseModel):
    id: str
    status: Literal["queued", "running", "done", "failed", "cancelled"]
    table_id: str
    models: list[str]
    request: RequestForm = Field(description="the job's request in its one form "
                                 "(brdffit.request.FitRequest.to_dict()): a single model "
                                 "as a list, every option left out with its default")
    attempts: int = Field(description="runs started so far (a server restart may re-run a job)")
    reason: str | None = Field(None, description="why the job failed or was cancelled")
    progress: Progress | None = Field(None, description="while running: stage and fraction")
    note: str | None = Field(None, description="what happened on the way, e.g. a re-run")
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    run_seconds: float | None = Field(
        None, description="seconds its worker spent on it, reading the table and fitting, "
        "compiling included where it compiled programs first (the server's cost estimate "
        "learns its machine's speed from the jobs that did not compile and did the work "
        "it counts); null until done")
    result: FitResultOut | None = Field(None, description="the best fit, once done")
    results: list[FitResultOut] | None = Field(None, description="every model's fit, in order")


def _time(t: float | None) -> datetime | None:
    return None if t is None else datetime.fromtimestamp(t, UTC)


def _out(job: JobRecord) -> JobOut:
    return JobOut(
        id=job.id, status=job.status, table_id=job.table_id, models=job.models,
        request=RequestForm.model_validate(job.request), attempts=job.attempts, reason=job.reason,
        note=job.note, created_at=_time(job.created_at), started_at=_time(job.started_at),
        finished_at=_time(job.finished_at), run_seconds=job.run_s,
        progress=(Progress(stage=job.stage, fraction=job.fraction or 0.0)
                  if job.status == "running" and job.stage else None),
        result=chosen_result(job.results) if job.results else None, results=job.results,
    )


def _job_or_404(store: Store, job_id: str) -> JobRecord:
    job = store.get_job(job_id)
    if job is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no fit job {job_id}")
    return job


async def finished_fit(store: Store, job_id: str, model: str | None,
                       what: str) -> tuple[JobRecord, dict]:
    """A done job and one of its fits (``model``'s, or the best): 404 for no such job
    or model, 409 while the job is not done (``what`` names what waits on it)."""
    job = await run_in_threadpool(_job_or_404, store, job_id)
    if job.status != "done":
        why = f": {job.reason}" if job.reason else ""
        # a failed or cancelled job will never be done: it has none, rather than not yet
        when = (f"{what} exist once it is done" if job.status in ("queued", "running")
                else f"it has no {what}: they exist for a fit that is done")
        raise HTTPException(status.HTTP_409_CONFLICT, f"fit job {job_id} is {job.status}{why}; "
                                                      f"{when}")
    fitted = ", ".join(r["model"] for r in job.results)
    if model is None or (model == options.AUTO and options.AUTO in job.models):
        return job, chosen_result(job.results)  # an auto job's: the chosen fit
    result = next((r for r in job.results if r["model"] == model), None)
    if result is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"fit job {job_id} has no {model!r} fit; "
                                                       f"it has {fitted}")
    return job, result


def json_body(request: Request) -> None:
    """A fit request is JSON: one sent as text/plain or a form was answered 422 'Input
    should be a valid dictionary', which names no fault the sender can see."""
    media = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if media != "application/json" and not media.endswith("+json"):
        raise HTTPException(status.HTTP_415_UNSUPPORTED_MEDIA_TYPE,
                            f"Content-Type {media or 'none'!r}: a fit request is a JSON "
                            "object, sent as application/json")


@router.post(
    "",
    status_code=status.HTTP_202_ACCEPTED,
    summary="Queue a fit",
    dependencies=[Depends(json_body)],
    responses={
        415: {"model": ErrorMessage, "description": "the body is not sent as JSON"},
        202: {"description": "queued", "links": {
            "GetFit": {"operationId": "get_fit", "parameters": {"job_id": "$response.body#/id"}},
            "GetPlot": {"operationId": "get_plot", "parameters": {"job_id": "$response.body#/id"}},
        }},
        404: {"model": ErrorMessage, "description": "no such table"},
    },
)
def create_fit(body: FitJobRequest, response: Response, store: StoreDep, queue: QueueDep,
               settings: SettingsDep) -> JobOut:
    try:
        job = fits.create(store, settings, body.table_id, body.request_dict())
    except fits.TableNotFound as e:
        raise HTTPException(status.HTTP_404_NOT_FOUND, str(e)) from None
    except (fits.OverLimits, FitInputError) as e:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, short(str(e))) from None
    queue.notify()
    response.headers["Location"] = f"/v1/fits/{job.id}"
    return _out(job)


class EstimateOut(BaseModel):
    """What a fit request would cost on its table, and whether this server takes it."""

    table_id: str
    models: list[str] = Field(description="the job's models, as it would list them ('auto': its "
                              "candidates are in detail)")
    seconds: float = Field(description="estimated seconds of the job's worker once its "
                           "programs are compiled (a worker's first job of these options "
                           "compiles first: seconds more), with this server's machine_factor "
                           "(to compare with a done job's run_seconds, which it is above)")
    memory_mib: float = Field(description="estimated peak memory of the job's worker, MiB")
    machine_factor: float = Field(
        description="how much slower than the machine the estimate's constants were measured "
        "on this server's recent jobs ran (x1.2); 1 where none ran slower, or none ran yet")
    accepted: bool = Field(description="whether POST /v1/fits takes it now (within the "
                           "server's limits)")
    over_limits: str | None = Field(description="why not, as POST /v1/fits would answer: by "
                                    "how much, and what to ask for instead; null if accepted")
    limits: dict[str, float] = Field(description="the server's limits: seconds "
                                     "(BRDFFIT_MAX_JOB_ESTIMATE_S), memory_mib "
                                     "(BRDFFIT_MAX_JOB_MEMORY_MIB)")
    detail: str = Field(description="how the figures came about: the fits it counts, samples, "
                        "starts and steps")


@router.post(
    "/estimate",
    summary="What a fit would cost, before it is queued",
    dependencies=[Depends(json_body)],
    responses={
        415: {"model": ErrorMessage, "description": "the body is not sent as JSON"},
        404: {"model": ErrorMessage, "description": "no such table"},
    },
)
def estimate_fit(body: FitJobRequest, store: StoreDep, settings: SettingsDep) -> EstimateOut:
    """The body is POST /v1/fits's; nothing is queued. Over the server's limits is an
    answer here (200, ``accepted`` false), where POST /v1/fits refuses it (422)."""
    try:
        checked = fits.costed(store, settings, body.table_id, body.request_dict())
    except fits.TableNotFound as e:
        raise HTTPException(status.HTTP_404_NOT_FOUND, str(e)) from None
    except FitInputError as e:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, short(str(e))) from None
    cost = checked.cost
    return EstimateOut(
        table_id=body.table_id, models=list(checked.request.models),
        seconds=round(cost.seconds, 2), memory_mib=round(cost.memory_mib),
        machine_factor=round(checked.machine, 3), accepted=checked.over is None,
        over_limits=checked.over, detail=cost.detail,
        limits={"seconds": settings.max_job_estimate_s,
                "memory_mib": float(settings.max_job_memory_mib)})


class FitPage(BaseModel):
    items: list[JobOut] = Field(description="newest first")
    total: int = Field(description="jobs matching the filters, over all pages")
    next_cursor: str | None = Field(description="pass as ?cursor= for the next page; null: "
                                                "this was the last")


# 18 digits: a cursor is a row id, below SQLite's int64 limit (19 overflowed it: a 500)
Cursor = Annotated[str | None, Query(pattern=r"^[0-9]{1,18}$",
                                     description="next_cursor of the previous page")]


@router.get("", summary="List fit jobs, newest first (paged, filtered)")
def list_fits(
    store: StoreDep,
    limit: Annotated[int, Query(ge=1, le=500, description="jobs per page")] = 50,
    cursor: Cursor = None,
    status_: Annotated[Literal[STATUSES] | None,  # type: ignore[valid-type]
                       Query(alias="status", description="only jobs in this status")] = None,
    table_id: Annotated[str | None, Query(pattern=r"^[0-9a-f]{64}$",
                                          description="only fits of this table")] = None,
    model: Annotated[str | None, Query(max_length=64,
                                       description="only jobs that fit this model")] = None,
) -> FitPage:
    page = store.list_jobs(limit=limit, cursor=None if cursor is None else int(cursor),
                           status=status_, table_id=table_id, model=model)
    return FitPage(items=[_out(j) for j in page.items], total=page.total,
                   next_cursor=page.next_cursor)


@router.get("/{job_id}", summary="A fit job: status, and the result once done",
            responses={404: {"model": ErrorMessage, "description": "no such job"}})
def get_fit(job_id: JobId, store: StoreDep) -> JobOut:
    return _out(_job_or_404(store, job_id))


#: How long a cancel waits for a running job's worker to be stopped before answering.
CANCEL_WAIT_S = 2.0


@router.post(
    "/{job_id}/cancel",
    summary="Cancel a queued or running fit",
    responses={404: {"model": ErrorMessage, "description": "no such job"},
               409: {"model": ErrorMessage, "description": "the job has already ended (also: "
                     "it ended, done or failed, before the cancel reached its worker)"},
               202: {"description": "its worker was still being stopped when the answer "
                     "came: the job is running, and cancelled within seconds (poll it)"}},
)
async def cancel_fit(job_id: JobId, store: StoreDep, queue: QueueDep,
                     response: Response) -> JobOut:
    """A queued job is cancelled at once; a running one has its worker process
    stopped (its partial work is dropped) and is ``cancelled`` within a second or so.
    A job that ended meanwhile is a 409, as one that had ended before: the answer was a
    200 carrying ``done``, where 200 promises ``cancelled``."""
    if await run_in_threadpool(store.cancel_queued, job_id):
        return _out(await run_in_threadpool(_job_or_404, store, job_id))
    job = await run_in_threadpool(_job_or_404, store, job_id)
    if job.status != "running":
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"fit job {job_id} is {job.status}: there is nothing to cancel")
    queue.cancel_running(job_id)
    deadline = asyncio.get_running_loop().time() + CANCEL_WAIT_S
    while job.status == "running" and asyncio.get_running_loop().time() < deadline:
        await asyncio.sleep(0.05)
        job = await run_in_threadpool(_job_or_404, store, job_id)
    if job.status in ("done", "failed"):
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"fit job {job_id} ended ({job.status}) before the cancel reached "
                            "its worker: there was nothing left to cancel; its results are kept")
    if job.status == "running":
        response.status_code = status.HTTP_202_ACCEPTED  # its worker is still being stopped
    return _out(job)


@router.delete(
    "/{job_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a finished fit job, its results and plots",
    responses={404: {"model": ErrorMessage, "description": "no such job"},
               409: {"model": ErrorMessage, "description": "queued or running: cancel it first"}},
)
def delete_fit(job_id: JobId, store: StoreDep) -> Response:
    why = store.delete_job(job_id)
    if why == "gone":
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no fit job {job_id}")
    if why is not None:
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"fit job {job_id} is {why}; cancel it first "
                            f"(POST /v1/fits/{job_id}/cancel)")
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.get(
    "/{job_id}/plots/{kind}.png",
    summary="A plot of a finished fit (PNG)",
    response_class=Response,
    responses={
        200: {"content": {"image/png": {}}, "description": "the plot"},
        404: {"model": ErrorMessage, "description": "no such job, or no such model in it"},
        409: {"model": ErrorMessage, "description": "the job is not done (queued, running,"
                                                    " failed)"},
        503: {"model": ErrorMessage, "description": "the worker died; try again"},
    },
)
async def get_plot(
    job_id: JobId,
    kind: PlotKind,
    store: StoreDep,
    runner: RunnerDep,
    model: FitModel = None,
    exposure_ev: Annotated[float, Query(
        ge=EXPOSURE_EV_RANGE[0], le=EXPOSURE_EV_RANGE[1], multiple_of=0.25, allow_inf_nan=False,
        description="stops brighter (+) or darker (-) than the one exposure the sphere "
                    "renders share, applied before tone mapping; for spheres and report "
                    "only")] = 0.0,
) -> Response:
    # on the quarter-stop grid exactly: multiple_of has a tolerance, and 1e-10, 1e-300 and
    # 2.000000000000001 each passed it, each a new render and a cached file of its own
    exposure_ev = round(exposure_ev * 4) / 4 + 0.0  # + 0.0: never -0.0
    if (why := exposure_refused(kind.value, exposure_ev)) is not None:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_ENTITY, why)
    job, result = await finished_fit(store, job_id, model, "plots")
    if kind.value in SAMPLE_KINDS and (result.get("input") or {}).get("fitted_at") != "samples":
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_ENTITY,
                            f"the {kind.value} plot draws a sample list's fit at each sample; "
                            f"fit job {job_id} fitted a MERL table: plot one of "
                            f"{', '.join(KINDS)}")
    if kind.value in SELECTION_KINDS and not (result.get("selection") or {}).get("ranking"):
        ran_auto = any((r.get("selection") or {}).get("ranking") for r in job.results)
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_ENTITY,
                            f"the {kind.value} plot draws auto's candidates and its choice; "
                            + (f"the {result['model']} fit of job {job_id} is a candidate, "
                               "not auto's choice: ask for the chosen fit's (no ?model=)"
                               if ran_auto else
                               f"fit job {job_id} fitted the models it named, without auto: "
                               f"plot one of {', '.join(KINDS)}"))
    path = store.plot_path(job_id, result["model"], kind.value, exposure_ev)
    if not path.exists():
        # Rendered on first request, in a worker (a second or two of matplotlib
        # and JAX), then served from the data dir.
        table = await run_in_threadpool(store.get_table, job.table_id)
        if table is None:
            raise await _deleted(store, job_id, job.table_id)
        try:
            outcome = await runner.run(tasks.render_plot, str(store.table_path(job.table_id)),
                                       table.name, result, kind.value, exposure_ev,
                                       limit_s=PLOT_LIMIT_S)
        except (WorkerLost, TimeLimitExceeded) as e:
            raise worker_unavailable(e, f"the {kind.value} plot") from None
        if not outcome.ok and not store.table_path(job.table_id).exists():
            # the table (and the job, with_fits) deleted while the plot waited for a
            # worker: a 500 that quoted the data dir's path of the file, where it is a 404
            raise await _deleted(store, job_id, job.table_id)
        if not outcome.ok:  # the server's fault, not the request's
            log.error("plot %s of job %s failed:\n%s", kind.value, job_id, outcome.traceback)
            raise HTTPException(status.HTTP_500_INTERNAL_SERVER_ERROR,
                                f"rendering the {kind.value} plot failed: {outcome.reason}")
        if not await kept_for_the_job(store, job_id, path, outcome.value):
            raise HTTPException(status.HTTP_404_NOT_FOUND,
                                f"no fit job {job_id}: deleted while its plot was drawn")
        return Response(outcome.value, media_type="image/png")
    return Response(await run_in_threadpool(path.read_bytes), media_type="image/png")


def worker_unavailable(e: WorkerLost | TimeLimitExceeded, what: str) -> HTTPException:
    """The 503 of a task (``what``: "the spheres plot") whose worker died under it, or
    that ran past its time limit (its worker replaced): try again, sooner or later."""
    if isinstance(e, TimeLimitExceeded):
        return HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE,
                             f"{what} {e}; try again later", headers={"Retry-After": "30"})
    return HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE, f"{e}; try again",
                         headers={"Retry-After": "5"})


async def _deleted(store, job_id: str, table_id: str) -> HTTPException:
    """The 404 of a plot whose job, or whose job's table, was deleted while it was asked
    for."""
    if await run_in_threadpool(store.get_job, job_id) is None:
        return HTTPException(status.HTTP_404_NOT_FOUND,
                             f"no fit job {job_id}: deleted while its plot was drawn")
    return HTTPException(status.HTTP_404_NOT_FOUND,
                         f"no table {table_id}: fit job {job_id}'s table was deleted, and a "
                         "plot draws the fit beside its table")


async def kept_for_the_job(store, job_id: str, path, data: bytes) -> bool:
    """``data`` kept at ``path``, in job ``job_id``'s folder of plots and exports;
    False (and the folder removed) where the job was deleted meanwhile: its folder went
    before this file came, and the file would stay on disk for good (a delete after
    this look removes it)."""
    await run_in_threadpool(_write_atomic, path, data)
    if await run_in_threadpool(store.get_job, job_id) is None:
        await run_in_threadpool(shutil.rmtree, store.plots_dir / job_id, True)
        return False
    return True


def _write_atomic(path, data: bytes) -> None:
    """``data`` into ``path`` (its folders made) by a rename: a reader sees it whole."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{id(data)}")
    tmp.write_bytes(data)
    os.replace(tmp, path)
