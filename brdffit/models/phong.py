"""Normalised Phong: lobe = (n+2)/(2 pi) max(0, r . wo)^n, r = (-wi.x, -wi.y, wi.z).

| name | range        | meaning                 |
|------|--------------|-------------------------|
| kd   | [0, inf)     | diffuse albedo, RGB     |
| ks   | [0, inf)     | specular scale, RGB     |
| n    | [0.1, 1e6]   | Phong exponent          |

The fit keeps ``n`` in [0.1, 1e6] on a log scale; docs/models.md only asks n > 0.
"""

from __future__ import annotations

import jax.numpy as jnp

from .base import KD, KS, AbstractLobeModel, ParamSpec
from .guarded import safe_pow

N_EXP = ParamSpec("n", "specular exponent", 0.1, 1e6, scale="log")
N_GRID = tuple({"n": float(n)} for n in (2, 8, 30, 100, 400, 1500, 6000, 25000))


class Phong(AbstractLobeModel):
    name = "phong"
    auto_candidate = True
    example_params = {"kd": [0.2, 0.15, 0.1], "ks": [0.4, 0.3, 0.2], "n": 80.0}
    param_specs = (KD, KS, N_EXP)
    shape_grid = N_GRID

    def lobe(self, params, frame):
        r_dot_o = frame.cos_i * frame.cos_o - frame.dot_xy
        n = params["n"]
        return (n + 2.0) / (2.0 * jnp.pi) * safe_pow(r_dot_o, n)
