"""``/v1/models``: the models a fit can use, with their parameters and ranges."""

from __future__ import annotations

from fastapi import APIRouter, Depends
from pydantic import BaseModel, Field

from api.deps import require_token
from api.errors import ERROR_RESPONSES
from brdffit.models import describe

router = APIRouter(prefix="/v1/models", tags=["models"], dependencies=[Depends(require_token)],
                   responses=ERROR_RESPONSES)


class ParamInfo(BaseModel):
    name: str
    size: int
    range: str
    lower: float
    upper: float | None
    doc: str
    physical_upper: float | None = Field(
        None, description="the upper bound in a physically bounded fit (options.physical)")


class ModelInfo(BaseModel):
    name: str
    params: list[ParamInfo]
    n_params: int
    doc: str
    parent: str | None
    mono: bool
    mono_n_params: int | None = Field(
        None, description="parameters of the model's `_mono` variant (one grey specular "
                          "scale), where it has one")
    mono_params: list[str] = Field(
        [], description="what the `_mono` variant makes one grey value (`ks`, `ks1`, `ks2`, "
                        "`specular_color`): a specular lobe's colour alone")
    least_starts: int = Field(
        1, description="the fewest starts a fit of it refines, whatever `starts` asks (a "
                       "thin film's many modes); its result's notes say so")


@router.get("", summary="The registered models (as `brdffit models --json`)")
def list_models() -> list[ModelInfo]:
    return describe()
