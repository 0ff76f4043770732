"""The analytic BRDF models of MODELS.md, by name.

A new model is one module plus one line in ``REGISTRY``.
"""

from __future__ import annotations

from .base import AbstractBRDFModel, AbstractLobeModel, ParamSpec, Params
from .beckmann import Beckmann
from .blinn_phong import BlinnPhong
from .ggx import GGX
from .lambert import Lambert
from .oren_nayar import OrenNayar
from .phong import Phong

#: Ordered cheapest to richest.
REGISTRY: dict[str, AbstractBRDFModel] = {
    m.name: m
    for m in (Lambert(), OrenNayar(), BlinnPhong(), Phong(), Beckmann(), GGX())
}


class UnknownModelError(KeyError):
    """A model name that is not in the registry."""

    def __str__(self) -> str:  # KeyError quotes its message otherwise
        return self.args[0]


def get(name: str | AbstractBRDFModel) -> AbstractBRDFModel:
    """The model called ``name`` (a model instance is returned as is)."""
    if isinstance(name, AbstractBRDFModel):
        return name
    try:
        return REGISTRY[name]
    except KeyError:
        raise UnknownModelError(
            f"unknown model {name!r}; choose one of {', '.join(REGISTRY)}"
        ) from None


__all__ = [
    "REGISTRY",
    "AbstractBRDFModel",
    "AbstractLobeModel",
    "ParamSpec",
    "Params",
    "UnknownModelError",
    "get",
]
