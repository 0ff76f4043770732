"""Three GGX lobes over a Lambertian base, sharing one Schlick Fresnel term.

f = kd/pi + F(cos_d) * (ks1 DG(alpha1) + ks2 DG(alpha2) + ks3 DG(alpha3)),
with DG and F as in :mod:`brdffit.models.ggx2`.

| name   | range      | meaning                                          |
|--------|------------|--------------------------------------------------|
| kd     | [0, inf)   | diffuse albedo, RGB                              |
| ks1    | [0, inf)   | scale of the first lobe, RGB                     |
| alpha1 | [1e-3, 2]  | roughness of the first lobe (log scale in a fit) |
| ks2    | [0, inf)   | scale of the second lobe, RGB                    |
| alpha2 | [1e-3, 2]  | roughness of the second lobe (log scale)         |
| ks3    | [0, inf)   | scale of the third lobe, RGB                     |
| alpha3 | [1e-3, 2]  | roughness of the third lobe (log scale)          |
| f0     | [0, 1]     | Schlick reflectance at normal incidence          |

Why a third lobe: under the log loss, ggx2 spends its broad lobe on the haze and the
grazing bins that outnumber the highlight's, and leaves the highlight too dim or too
broad (steel, aluminium, brass and the metallic paints read poor on the lit sphere).
A third lobe lets the fit keep a sharp peak, a glossy shoulder and the haze at once:
on MERL's metals and metallic paints it lifted the sphere render by up to 7 dB under
the log loss (docs/models.md). It is no renderer's layer: exported by a refit, as
ggx2 is.

It contains ggx2 (``ks3 = 0``): fitted from ggx2's optimum (``parent``), with the
third lobe started at several widths (``parent_scan``), beside its own grid of
shapes, so it never ends worse than ggx2.
"""

from __future__ import annotations

import numpy as np

from .base import KD, ParamSpec
from .ggx2 import ALPHA1, ALPHA2, GGX2, KS1, KS2
from .microfacet import ALPHA_GRID, F0

KS3 = ParamSpec("ks3", "scale of the third lobe (RGB)", 0.0, None, rgb=True)
ALPHA3 = ParamSpec("alpha3", "roughness of the third lobe", 1e-3, 2.0, scale="log")

#: The third lobe's widths a fit from ggx2's optimum starts at, each beside the two
#: lobes there: sharper than a mirror-like peak, at a glossy shoulder, at a haze (a
#: third lobe started only sharper than the first stayed at zero on chrome and
#: tungsten-carbide). Its scale starts small but where the softplus has a slope.
THIRD_LOBE_STARTS = (0.002, 0.006, 0.02, 0.06, 0.2, 0.6)
THIRD_LOBE_SCALE = 0.01


class GGX3(GGX2):
    name = "ggx3"
    auto_candidate = False
    param_specs = (KD, KS1, ALPHA1, KS2, ALPHA2, KS3, ALPHA3, F0)
    # Each lobe at least 3x broader than the one before (closer pairs are one lobe
    # twice); f0 below its bound, as ggx2's.
    shape_grid = tuple(
        {"alpha1": a1, "alpha2": a2, "alpha3": a3, "f0": f0}
        for a1 in ALPHA_GRID
        for a2 in ALPHA_GRID
        if a2 >= 3.0 * a1
        for a3 in ALPHA_GRID
        if a3 >= 3.0 * a2
        for f0 in (0.3, 0.95)
    )
    parent = "ggx2"
    parent_scan = tuple({"alpha3": a, "ks3": np.full(3, THIRD_LOBE_SCALE)}
                        for a in THIRD_LOBE_STARTS)
    lobe_scales = ("ks1", "ks2", "ks3")
    lobe_alphas = ("alpha1", "alpha2", "alpha3")

    def embed_parent(self, parent_params: dict) -> dict:
        """ggx2's two lobes, the third off (``ks3 = 0``) and a third of the sharper's
        width; ``parent_scan`` turns it on at each of its widths."""
        sharper = min(float(np.asarray(parent_params["alpha1"])),
                      float(np.asarray(parent_params["alpha2"])))
        return {**{k: parent_params[k] for k in ("kd", "ks1", "alpha1", "ks2", "alpha2",
                                                  "f0")},
                "ks3": np.zeros(3), "alpha3": max(ALPHA3.lower, sharper / 3.0)}
