"""brdffit: fit analytic BRDF models to measured MERL tables.

    from brdffit import fit, merl
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

# public name -> the module that defines it (a module's own name: the module itself)
_LAZY = {
    "BrdffitError": "errors",
    "FitInputError": "errors",
    "MerlFormatError": "errors",
    "FitResult": "result",
    "MerlTable": "merl",
    "fit": "fitting",
    "merl": "merl",
    "models": "models",
}

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
    from . import merl, models
    from .errors import BrdffitError, FitInputError, MerlFormatError
    from .fitting import fit
    from .merl import MerlTable
    from .result import FitResult


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    module = importlib.import_module(f"{__name__}.{_LAZY[name]}")
    value = module if name == _LAZY[name] else getattr(module, name)
    globals()[name] = value  # the next access skips __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
