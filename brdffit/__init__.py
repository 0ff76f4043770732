"""brdffit: fit analytic BRDF models to measured MERL tables.

    from brdffit import fit, merl
    result = fit(merl.read("gold-metallic-paint.binary"), "ggx")
    print(result.params, result.log_rmse)
"""

from __future__ import annotations

from . import runtime

runtime.configure()

from . import merl, models  # noqa: E402
from .errors import BrdffitError, FitInputError, MerlFormatError  # noqa: E402
from .fitting import FitResult, fit  # noqa: E402
from .merl import MerlTable  # noqa: E402

__version__ = "0.1.0"

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
