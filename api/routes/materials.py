"""``/v1/materials``: the shipped real materials, stored as tables on request.

``data_synth.nbrdf`` rebuilds the 100 MERL materials from their published neural
BRDFs, offline. ``POST /v1/materials/{name}`` makes that table with the library
and stores it through the upload's own path (validated by the reader, named by its
sha256), so a material picked here is an ordinary table afterwards. The service
image ships without ``data_synth``: there the list is empty and says why.
"""

from __future__ import annotations

import logging
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path, Response, status
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from api import tasks
from api.deps import RunnerDep, StoreDep, require_token
from api.errors import ERROR_RESPONSES, ErrorMessage
from api.routes.fits import worker_unavailable
from api.routes.tables import TableOut, table_out
from api.runner import TimeLimitExceeded, WorkerLost
from api.services import tables

log = logging.getLogger("brdffit.api")

#: The longest a material's rebuild may run in its worker (a few seconds).
MATERIAL_LIMIT_S = 300.0

router = APIRouter(prefix="/v1/materials", tags=["tables"], dependencies=[Depends(require_token)],
                   responses=ERROR_RESPONSES)

MaterialName = Annotated[str, Path(pattern=r"^[a-z0-9][a-z0-9-]{0,63}$",
                                   description="a name from GET /v1/materials")]


class MaterialList(BaseModel):
    names: list[str] = Field(description="the shipped MERL materials (neural BRDF rebuilds)")
    note: str | None = Field(None, description="why the list is empty, when it is")


@router.get("", summary="The shipped real materials (MERL, rebuilt offline)")
def list_materials() -> MaterialList:
    names = tables.material_names()
    if names is None:
        return MaterialList(names=[], note="this installation has no data_synth package: "
                                           "upload a .binary table instead")
    return MaterialList(names=names)


@router.post(
    "/{name}",
    status_code=status.HTTP_201_CREATED,
    summary="Store a shipped material as a table",
    responses={200: {"model": TableOut, "description": "stored before: same id"},
               404: {"model": ErrorMessage, "description": "no such material here"}},
)
async def add_material(name: MaterialName, response: Response, store: StoreDep,
                       runner: RunnerDep) -> TableOut:
    if name not in (tables.material_names() or ()):
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"no shipped material {name!r}; GET /v1/materials lists them")
    # rebuilt in a worker (JAX), as a fit is; hashed and stored here (numpy alone)
    path = await run_in_threadpool(tables.material_file, store)
    try:
        outcome = await runner.run(tasks.write_material, name, str(path),
                                   limit_s=MATERIAL_LIMIT_S)
        if not outcome.ok:
            log.error("material %s not rebuilt:\n%s", name, outcome.traceback)
            raise HTTPException(status.HTTP_500_INTERNAL_SERVER_ERROR,
                                f"rebuilding the material {name} failed: {outcome.reason}")
        record, created = await run_in_threadpool(tables.store_material_file, store, name,
                                                  path)
    except (WorkerLost, TimeLimitExceeded) as e:
        raise worker_unavailable(e, f"rebuilding the material {name}") from None
    finally:  # stored (renamed away) or not, nothing is left in tmp
        path.unlink(missing_ok=True)
    if not created:
        response.status_code = status.HTTP_200_OK
    response.headers["Location"] = f"/v1/tables/{record.id}"
    return table_out(record)
