"""``/v1/models``: the models a fit can use, with their parameters and ranges."""

from __future__ import annotations

from fastapi import APIRouter, Depends
from pydantic import BaseModel

from brdffit.commands.models import describe

from ..deps import require_token
from ..errors import ERROR_RESPONSES

router = APIRouter(prefix="/v1/models", tags=["models"], dependencies=[Depends(require_token)],
                   responses=ERROR_RESPONSES)


class ParamInfo(BaseModel):
    name: str
    size: int
    range: str
    lower: float
    upper: float | None
    doc: str


class ModelInfo(BaseModel):
    name: str
    params: list[ParamInfo]
    n_params: int
    doc: str


@router.get("", summary="The registered models (as `brdffit models --json`)")
def list_models() -> list[ModelInfo]:
    return describe()
