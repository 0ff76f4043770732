"""``/v1/materials``: the shipped real materials, stored as tables on request.

``data_synth.nbrdf`` rebuilds the 100 MERL materials from their published neural
BRDFs, offline. ``POST /v1/materials/{name}`` makes that table with the library
and stores it through the upload's own path (validated by the reader, named by its
sha256), so a material picked here is an ordinary table afterwards. The service
image ships without ``data_synth``: there the list is empty and says why.
"""

from __future__ import annotations

import hashlib
import tempfile
from pathlib import Path as FilePath
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path, Response, status
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from api.deps import StoreDep, require_token
from api.errors import ERROR_RESPONSES, ErrorMessage
from api.routes.tables import TableOut, _out, _validate_and_store
from api.store import Store, TableRecord
from brdffit.io import merl

router = APIRouter(prefix="/v1/materials", tags=["tables"], dependencies=[Depends(require_token)],
                   responses=ERROR_RESPONSES)

MaterialName = Annotated[str, Path(pattern=r"^[a-z0-9][a-z0-9-]{0,63}$",
                                   description="a name from GET /v1/materials")]


def _nbrdf():
    try:
        from data_synth import nbrdf
    except ImportError:  # the service image holds brdffit and api only
        return None
    return nbrdf


class MaterialList(BaseModel):
    names: list[str] = Field(description="the shipped MERL materials (neural BRDF rebuilds)")
    note: str | None = Field(None, description="why the list is empty, when it is")


@router.get("", summary="The shipped real materials (MERL, rebuilt offline)")
def list_materials() -> MaterialList:
    nbrdf = _nbrdf()
    if nbrdf is None:
        return MaterialList(names=[], note="this installation has no data_synth package: "
                                           "upload a .binary table instead")
    return MaterialList(names=list(nbrdf.material_names()))


def _make_and_store(store: Store, name: str) -> tuple[TableRecord, bool]:
    nbrdf = _nbrdf()
    fd, tmp = tempfile.mkstemp(prefix="material-", suffix=".binary", dir=store.tmp_dir)
    path = FilePath(tmp)
    try:
        with open(fd, "wb") as f:
            f.write(merl.to_bytes(nbrdf.make_table(name)))
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
        return _validate_and_store(store, path, digest, path.stat().st_size, f"{name}.binary")
    finally:
        path.unlink(missing_ok=True)


@router.post(
    "/{name}",
    status_code=status.HTTP_201_CREATED,
    summary="Store a shipped material as a table",
    responses={200: {"model": TableOut, "description": "stored before: same id"},
               404: {"model": ErrorMessage, "description": "no such material here"}},
)
async def add_material(name: MaterialName, response: Response, store: StoreDep) -> TableOut:
    nbrdf = _nbrdf()
    if nbrdf is None or name not in nbrdf.material_names():
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"no shipped material {name!r}; GET /v1/materials lists them")
    # About a second of numpy and a 35 MB write: off the event loop.
    record, created = await run_in_threadpool(_make_and_store, store, name)
    if not created:
        response.status_code = status.HTTP_200_OK
    response.headers["Location"] = f"/v1/tables/{record.id}"
    return _out(record)
