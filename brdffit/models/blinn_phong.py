"""Blinn-Phong: lobe = (n+2)/(2 pi) cos_h^n (docs/models.md normalisation).

| name | range        | meaning                 |
|------|--------------|-------------------------|
| kd   | [0, inf)     | diffuse albedo, RGB     |
| ks   | [0, inf)     | specular scale, RGB     |
| n    | [0.1, 1e6]   | Blinn exponent          |

Note: with this normalisation the lobe's directional albedo approaches 4 for a
sharp lobe at normal incidence (dw_o = 4 cos_d dw_h), so energy is conserved for
``kd + 4 ks <= 1``, not ``kd + ks <= 1``. The formula is kept as the contract
writes it; fitted ``ks`` values are comparable across tools that use it.
"""

from __future__ import annotations

import jax.numpy as jnp

from .base import KD, KS, AbstractLobeModel
from .guarded import safe_pow
from .phong import N_EXP, N_GRID


class BlinnPhong(AbstractLobeModel):
    name = "blinn_phong"
    auto_candidate = True
    example_params = {"kd": [0.2, 0.15, 0.1], "ks": [0.4, 0.3, 0.2], "n": 120.0}
    param_specs = (KD, KS, N_EXP)
    shape_grid = N_GRID

    def lobe(self, params, frame):
        n = params["n"]
        return (n + 2.0) / (2.0 * jnp.pi) * safe_pow(frame.cos_h, n)
