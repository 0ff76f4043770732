"""``/v1/materials``: the shipped real materials, stored as tables on request.

``data_synth.nbrdf`` rebuilds the 100 MERL materials from their published neural
BRDFs, offline. ``POST /v1/materials/{name}`` makes that table with the library
and stores it through the upload's own path (validated by the reader, named by its
sha256), so a material picked here is an ordinary table afterwards. The service
image ships without ``data_synth``: there the list is empty and says why.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path, Response, status
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from api.deps import StoreDep, require_token
from api.errors import ERROR_RESPONSES, ErrorMessage
from api.routes.tables import TableOut, table_out
from api.services import tables

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
async def add_material(name: MaterialName, response: Response, store: StoreDep) -> TableOut:
    if name not in (tables.material_names() or ()):
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"no shipped material {name!r}; GET /v1/materials lists them")
    # About a second of numpy and a 35 MB write: off the event loop.
    record, created = await run_in_threadpool(tables.store_material, store, name)
    if not created:
        response.status_code = status.HTTP_200_OK
    response.headers["Location"] = f"/v1/tables/{record.id}"
    return table_out(record)
