"""Three GGX lobes over a Lambertian base, sharing one Schlick Fresnel term.

f = kd/pi + F(cos_d) * (ks1 DG(alpha1) + ks2 DG(alpha2) + ks3 DG(alpha3)),
with DG and F as in :mod:`brdffit.models.ggx2`.

ggx2's parameters (kd, ks1, alpha1, ks2, alpha2, f0), and:

| name   | range      | meaning                                          |
|--------|------------|--------------------------------------------------|
| ks3    | [0, inf)   | scale of the third lobe, RGB                     |
| alpha3 | [1e-3, 2]  | roughness of the third lobe (log scale in a fit) |

Why a third lobe: under the log loss, ggx2 spends its broad lobe on the haze and the
grazing bins that outnumber the highlight's, and leaves the highlight too dim or too
broad (steel, aluminium, brass and the metallic paints read poor on the lit sphere).
A third lobe lets the fit keep a sharp peak, a glossy shoulder and the haze at once:
on MERL's metals and metallic paints it lifted the sphere render by up to 7.7 dB under
the log loss (docs/models.md). It is no renderer's layer: exported by a refit, as
ggx2 is.

It contains ggx2 (``ks3 = 0``): fitted from ggx2's optimum (``parent``), with the
third lobe started at several widths (``parent_scan``), beside its own grid of
shapes, so it never ends worse than ggx2.
"""

from __future__ import annotations

import numpy as np

from .base import KD, ParamSpec
from .ggx2 import ALPHA1, ALPHA2, GGX2, KS1, KS2, lobe_grid, new_lobe_scan
from .microfacet import F0

KS3 = ParamSpec("ks3", "scale of the third lobe (RGB)", 0.0, None, rgb=True)
ALPHA3 = ParamSpec("alpha3", "roughness of the third lobe", 1e-3, 2.0, scale="log")

class GGX3(GGX2):
    name = "ggx3"
    auto_candidate = False
    param_specs = (KD, KS1, ALPHA1, KS2, ALPHA2, KS3, ALPHA3, F0)
    lobe_scales = ("ks1", "ks2", "ks3")
    lobe_alphas = ("alpha1", "alpha2", "alpha3")
    shape_grid = lobe_grid(lobe_alphas)
    parent = "ggx2"
    parent_scan = new_lobe_scan(lobe_scales[-1], lobe_alphas[-1])

    def embed_parent(self, parent_params: dict) -> dict:
        """The parent's lobes, the new one off (scale 0) and a third of the sharpest's
        width; ``parent_scan`` turns it on at each of its widths."""
        new_scale, new_alpha = self.lobe_scales[-1], self.lobe_alphas[-1]
        floor = next(s.lower for s in self.param_specs if s.name == new_alpha)
        sharpest = min(float(np.asarray(parent_params[a])) for a in self.lobe_alphas[:-1])
        return {**{k: parent_params[k] for k in ("kd", *self.lobe_scales[:-1],
                                                  *self.lobe_alphas[:-1], "f0")},
                new_scale: np.zeros(3), new_alpha: max(floor, sharpest / 3.0)}
