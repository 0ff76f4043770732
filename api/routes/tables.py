"""``/v1/tables``: upload a measured table (MERL, or samples: ASTM, CSV, HDF5, MATLAB,
.npz, Excel .xlsx), read its summary.

An upload is streamed to a temporary file in the data dir while it is hashed and
counted (a 35 MB table never sits whole in the server's memory, and a body over
the cap is cut off as soon as it passes it), then validated by the library's
reader, then renamed to its sha256: uploading the same bytes again is a no-op
that returns the same id.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import AsyncIterator
from datetime import UTC, datetime
from pathlib import Path as FilePath
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path, Query, Request, Response, status
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field
from starlette.datastructures import UploadFile
from starlette.formparsers import MultiPartException, MultiPartParser
from starlette.requests import ClientDisconnect

from api.deps import SettingsDep, StoreDep, require_token
from api.errors import ERROR_RESPONSES, ErrorMessage
from api.services import tables
from api.store import TableRecord

router = APIRouter(prefix="/v1/tables", tags=["tables"], dependencies=[Depends(require_token)],
                   responses=ERROR_RESPONSES)

TableId = Annotated[str, Path(pattern=r"^[0-9a-f]{64}$", description="sha256 of the table file")]

#: Body types taken as the raw file. No Content-Type at all counts as raw too
#: (RFC 9110 lets a recipient assume application/octet-stream).
RAW_TYPES = ("application/octet-stream", "application/x-merl-binary")
CHUNK = 1 << 20
#: How far past the cap a body is still read (and dropped) to answer it cleanly.
DRAIN = 16 << 20
#: Longest table name kept (a file name's usual limit).
MAX_NAME = 255


class TableSummary(BaseModel):
    """What the table holds (``MerlTable.summary``); values in 1/sr, per R, G, B."""

    measured_bins: int
    unmeasured_bins: int
    nonfinite_bins: int = Field(description="bins with a NaN/Inf value: masked, not an error")
    min: list[float] = Field(description="smallest measured value per channel")
    median: list[float]
    max: list[float]
    input: dict | None = Field(
        default=None, description="an upload of samples (ASTM E1392, CSV/TSV, HDF5): their "
                                  "format and count and what binning them onto the MERL "
                                  "grid did (docs/measurements.md); null for a MERL table")


class TableOut(BaseModel):
    id: str = Field(description="sha256 of the file (of the file's sha256 and the sheet's "
                                "name, for a workbook's sheet named on upload): the same "
                                "bytes always get the same id")
    name: str = Field(description="the uploader's file name")
    size_bytes: int
    created_at: datetime
    summary: TableSummary


UPLOAD_BODY = {
    "required": True,
    "description": "A MERL .binary file: the raw bytes, or a multipart form with a `file` field.",
    "content": {
        "application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
        "multipart/form-data": {
            "schema": {"type": "object", "required": ["file"],
                       "properties": {"file": {"type": "string", "format": "binary"}}}
        },
    },
}


class _TooLarge(Exception):
    pass


def table_out(record: TableRecord) -> TableOut:
    summary = {k: v for k, v in record.summary.items() if k != "source"}
    return TableOut(id=record.id, name=record.name, size_bytes=record.size,
                    created_at=datetime.fromtimestamp(record.created_at, UTC),
                    summary=TableSummary(**summary))


async def _capped(stream: AsyncIterator[bytes], cap: int) -> AsyncIterator[bytes]:
    """``stream`` up to ``cap`` bytes; past it, raise :class:`_TooLarge`.

    Past the cap the rest of the body is read and dropped, up to :data:`DRAIN`
    more bytes, before the 413 goes out: a client that sends its whole body
    before reading the answer (httpx, requests; no ``Expect: 100-continue``)
    then sees the 413 instead of a connection reset. A larger excess is cut off.
    """
    seen = 0
    async for chunk in stream:
        seen += len(chunk)
        if seen > cap:
            break
        yield chunk
    else:
        return
    async for chunk in stream:
        seen += len(chunk)
        if seen > cap + DRAIN:
            break
    raise _TooLarge


async def _file_chunks(upload: UploadFile) -> AsyncIterator[bytes]:
    while chunk := await upload.read(CHUNK):
        yield chunk


async def _spool(chunks: AsyncIterator[bytes], directory: FilePath) -> tuple[FilePath, str, int]:
    """Write ``chunks`` to a temp file; returns (path, sha256, size)."""
    digest, size = hashlib.sha256(), 0
    fd, name = tempfile.mkstemp(prefix="upload-", suffix=".binary", dir=directory)
    path = FilePath(name)
    try:
        with os.fdopen(fd, "wb") as f:
            async for chunk in chunks:
                # Page-cache writes of <= 1 MiB: short enough for the event loop.
                f.write(chunk)
                digest.update(chunk)
                size += len(chunk)
    except BaseException:
        path.unlink(missing_ok=True)
        raise
    return path, digest.hexdigest(), size


def _too_large(cap: int) -> HTTPException:
    return HTTPException(status.HTTP_413_CONTENT_TOO_LARGE,
                         f"upload larger than the server's cap of {cap:,} bytes "
                         "(BRDFFIT_MAX_UPLOAD_BYTES); a MERL table is 34,992,012 bytes")


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    summary="Upload a MERL table",
    responses={
        201: {"description": "stored", "links": {"GetTable": {
            "operationId": "get_table", "parameters": {"table_id": "$response.body#/id"}}}},
        200: {"model": TableOut, "description": "these bytes were uploaded before: same id"},
        400: {"model": ErrorMessage, "description": "malformed multipart body"},
        413: {"model": ErrorMessage, "description": "body, or the sample list as stored, "
                                                    "over BRDFFIT_MAX_UPLOAD_BYTES"},
        415: {"model": ErrorMessage, "description": "neither raw bytes nor multipart"},
        422: {"model": ErrorMessage, "description": "not a valid MERL table (the detail says why)"},
    },
    openapi_extra={"requestBody": UPLOAD_BODY},
)
async def upload_table(
    request: Request,
    response: Response,
    store: StoreDep,
    settings: SettingsDep,
    name: Annotated[str | None, Query(max_length=MAX_NAME,
                                      description="file name to record")] = None,
    sheet: Annotated[str | None, Query(
        min_length=1, max_length=MAX_NAME,
        description="an Excel workbook's sheet of samples to store (default: its first "
                    "sheet of samples); refused for any other file. The id is then the "
                    "sha256 of the file's sha256 and the sheet's name "
                    "(api.services.tables.sheet_id): each sheet is a table of its own")] = None,
) -> TableOut:
    cap = settings.max_upload_bytes
    length = request.headers.get("content-length", "")
    if length.isdigit() and int(length) > cap + DRAIN:
        raise _too_large(cap)  # refused before reading a byte (see _capped for the rest)
    media = request.headers.get("content-type", RAW_TYPES[0]).split(";")[0].strip().lower()
    body = _capped(request.stream(), cap)
    form = None
    try:
        if media in RAW_TYPES:
            chunks = body
        elif media == "multipart/form-data":
            parser = MultiPartParser(request.headers, body, max_files=1, max_fields=8)
            form = await parser.parse()
            upload = form.get("file")
            if not form:  # python-multipart yields no parts for a body cut before its end
                raise HTTPException(status.HTTP_400_BAD_REQUEST,
                                    "malformed multipart body: no complete part (was it cut "
                                    "short?); the table goes in a 'file' field")
            if isinstance(upload, str):  # the field, as text: no filename= in its part
                raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                    "the multipart 'file' field came as text, not as a file "
                                    "(its part names no filename): send the file itself "
                                    "(curl -F file=@PATH, with the @)")
            if not isinstance(upload, UploadFile):
                raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                    "the multipart body needs the table in a 'file' field")
            sent = os.path.basename(upload.filename or "")
            if len(sent) > MAX_NAME:  # the same cap as ?name=
                raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                    f"the file name is {len(sent):,} characters; at most "
                                    f"{MAX_NAME} are kept (send a shorter one, or ?name=)")
            name = name or sent
            chunks = _file_chunks(upload)
        else:
            raise HTTPException(
                status.HTTP_415_UNSUPPORTED_MEDIA_TYPE,
                f"Content-Type {media!r} is not a table upload: send the raw file as "
                "application/octet-stream, or multipart/form-data with a 'file' field",
            )
        tmp, digest, size = await _spool(chunks, store.tmp_dir)
    except _TooLarge:
        raise _too_large(cap) from None
    except MultiPartException as e:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, f"malformed multipart body: {e}") from None
    except ClientDisconnect:  # nobody to answer; not a server error either
        raise HTTPException(status.HTTP_400_BAD_REQUEST, "client disconnected mid-upload") from None
    finally:
        if form is not None:
            await form.close()
    # a NUL is replaced, as an unpaired surrogate is: a sample list is stored as HDF5,
    # whose attributes cannot hold one (a 500), and a MERL table's name could
    name = (name or "upload").replace("\x00", "\ufffd")
    try:
        record, created = await run_in_threadpool(
            tables.validate_and_store, store, tmp, digest, size, name, cap, sheet)
    except tables.StoredTooLarge as e:  # the cap holds for what is kept, compressed or not
        raise HTTPException(status.HTTP_413_CONTENT_TOO_LARGE, str(e)) from None
    finally:
        tmp.unlink(missing_ok=True)
    if not created:
        response.status_code = status.HTTP_200_OK
    response.headers["Location"] = f"/v1/tables/{record.id}"
    return table_out(record)


@router.get("/{table_id}", summary="A table's summary",
            responses={404: {"model": ErrorMessage, "description": "no such table"}})
def get_table(table_id: TableId, store: StoreDep) -> TableOut:
    record = store.get_table(table_id)
    if record is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no table {table_id}")
    return table_out(record)


class TablePage(BaseModel):
    items: list[TableOut] = Field(description="newest first")
    total: int = Field(description="tables matching the filter, over all pages")
    next_cursor: str | None = Field(description="pass as ?cursor= for the next page; null: "
                                                "this was the last")


@router.get("", summary="List tables, newest first (paged, filtered)")
def list_tables(
    store: StoreDep,
    limit: Annotated[int, Query(ge=1, le=500, description="tables per page")] = 50,
    cursor: Annotated[str | None, Query(pattern=r"^[0-9]{1,18}$",
                                        description="next_cursor of the previous page")] = None,
    name: Annotated[str | None, Query(max_length=MAX_NAME,
                                      description="only tables whose name contains this "
                                                  "(case-insensitive)")] = None,
) -> TablePage:
    page = store.list_tables(limit=limit, cursor=None if cursor is None else int(cursor),
                             name=name)
    return TablePage(items=[table_out(t) for t in page.items], total=page.total,
                     next_cursor=page.next_cursor)


@router.delete(
    "/{table_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a table (and, with ?with_fits=true, its finished fit jobs)",
    responses={404: {"model": ErrorMessage, "description": "no such table"},
               409: {"model": ErrorMessage, "description": "fit jobs use it (the detail "
                                                           "says which kind)"}},
)
def delete_table(
    table_id: TableId,
    store: StoreDep,
    with_fits: Annotated[bool, Query(description="delete its finished fit jobs too")] = False,
) -> Response:
    why, count = store.delete_table(table_id, with_fits=with_fits)
    if why == "gone":
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no table {table_id}")
    if why == "active":
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"{count} queued or running fit job(s) use table {table_id}; "
                            "cancel them first (POST /v1/fits/{id}/cancel)")
    if why == "fits":
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"{count} fit job(s) use table {table_id}; delete them, or pass "
                            "?with_fits=true to delete them with the table")
    return Response(status_code=status.HTTP_204_NO_CONTENT)
