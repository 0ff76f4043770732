"""The analytic BRDF models of MODELS.md, by name.

A new model is one module plus one line in ``REGISTRY``.
"""

from __future__ import annotations

from .. import runtime

# float64 and the compile cache before any model (or anything that imports one:
# the fit, the loss, the renders) touches JAX
runtime.configure()

from ..errors import BrdffitError  # noqa: E402
from .base import AbstractBRDFModel, AbstractLobeModel, Params, ParamSpec  # noqa: E402
from .beckmann import Beckmann  # noqa: E402
from .blinn_phong import BlinnPhong  # noqa: E402
from .ggx import GGX  # noqa: E402
from .ggx2 import GGX2  # noqa: E402
from .lambert import Lambert  # noqa: E402
from .mono_ks import SUFFIX as _MONO  # noqa: E402
from .mono_ks import MonoKs, specular_colour_specs  # noqa: E402
from .oren_nayar import OrenNayar  # noqa: E402
from .phong import Phong  # noqa: E402

#: Ordered cheapest to richest.
REGISTRY: dict[str, AbstractBRDFModel] = {
    m.name: m
    for m in (
        Lambert(), OrenNayar(), BlinnPhong(), Phong(),
        Beckmann(), Beckmann(fresnel="dielectric"), GGX(), GGX(fresnel="dielectric"),
        GGX2(),
    )
}


class UnknownModelError(BrdffitError, KeyError):
    """A model name that is not in the registry (a KeyError for mapping-style callers)."""

    def __str__(self) -> str:  # KeyError quotes its message otherwise
        return self.args[0]


def get(name: str | AbstractBRDFModel) -> AbstractBRDFModel:
    """The model called ``name`` (a model instance is returned as is)."""
    if isinstance(name, AbstractBRDFModel):
        return name
    if name in REGISTRY:
        return REGISTRY[name]
    # "ggx_mono": the registered model with a grey specular scale (models/mono_ks.py)
    if isinstance(name, str) and name.endswith(_MONO):
        base = REGISTRY.get(name.removesuffix(_MONO))
        if base is not None and specular_colour_specs(base):
            return MonoKs(base)
    raise UnknownModelError(f"unknown model {name!r}; choose one of {', '.join(REGISTRY)}")


__all__ = [
    "REGISTRY",
    "AbstractBRDFModel",
    "AbstractLobeModel",
    "MonoKs",
    "ParamSpec",
    "Params",
    "UnknownModelError",
    "get",
]
