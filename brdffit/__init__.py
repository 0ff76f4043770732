"""brdffit: fit analytic BRDF models to measured MERL tables.

    from brdffit import fit

    from brdffit.io import merl
    result = fit(merl.read("gold-metallic-paint.binary"), "ggx")
    print(result.params, result.log_rmse)

The names below are imported on first use, not by ``import brdffit``: the HTTP
client (``brdffit.client``) and ``brdffit --help`` then load no JAX, and JAX's
settings (``brdffit.runtime``) are applied by the modules that compute with it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

# public name -> the module that defines it
_LAZY = {
    "BrdffitError": "errors",
    "FitInputError": "errors",
    "MerlFormatError": "errors",
    "FitResult": "fitting.result",
    "MerlTable": "io.merl",
    "fit": "fitting.pipeline",
}
# public name -> the module it is
_MODULES = {"merl": "io.merl", "models": "models"}

__all__ = [
    "BrdffitError",
    "FitInputError",
    "FitResult",
    "MerlFormatError",
    "MerlTable",
    "fit",
    "merl",
    "models",
]

if TYPE_CHECKING:
    from brdffit import models
    from brdffit.errors import BrdffitError, FitInputError, MerlFormatError
    from brdffit.fitting.pipeline import fit
    from brdffit.fitting.result import FitResult
    from brdffit.io import merl
    from brdffit.io.merl import MerlTable


def __getattr__(name: str):
    if name in _MODULES:
        value = importlib.import_module(f"{__name__}.{_MODULES[name]}")
    elif name in _LAZY:
        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value  # the next access skips __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY) | set(_MODULES))
