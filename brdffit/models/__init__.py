"""The analytic BRDF models of docs/models.md, by name.

Two layers, so that naming a model never waits for JAX:

- :mod:`.catalogue` (no JAX): the names, ``auto``, the ``_mono`` variants, each
  model's parameters, and the check every shell's model option goes through;
- :mod:`.registry` (JAX): the model objects, ``get(name)``, ``register(model)``.

``from brdffit.models import get`` (or ``REGISTRY``, or a model class) imports
the registry, and JAX, on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from brdffit.models.catalogue import (
    AUTO,
    UnknownModelError,
    check_name,
    describe,
    names,
)

# heavy name -> the module that defines it, imported on first access
_LAZY = {
    "REGISTRY": "registry",
    "BUILTIN": "registry",
    "get": "registry",
    "register": "registry",
    "AbstractBRDFModel": "base",
    "AbstractLobeModel": "base",
    "ParamSpec": "base",
    "Params": "base",
    "MonoKs": "mono_ks",
}

if TYPE_CHECKING:
    from brdffit.models.base import AbstractBRDFModel, AbstractLobeModel, Params, ParamSpec
    from brdffit.models.mono_ks import MonoKs
    from brdffit.models.registry import BUILTIN, REGISTRY, get, register


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    globals()[name] = value
    return value


__all__ = [
    "AUTO",
    "BUILTIN",
    "REGISTRY",
    "AbstractBRDFModel",
    "AbstractLobeModel",
    "MonoKs",
    "ParamSpec",
    "Params",
    "UnknownModelError",
    "check_name",
    "describe",
    "get",
    "names",
    "register",
]
