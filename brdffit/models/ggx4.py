"""Four GGX lobes over a Lambertian base, sharing one Schlick Fresnel term.

f = kd/pi + F(cos_d) * sum_i ks_i DG(alpha_i), i = 1..4, with DG and F as in
:mod:`brdffit.models.ggx2`: ggx3 (:mod:`brdffit.models.ggx3`) with a fourth lobe
(``ks4``, RGB, [0, inf); ``alpha4``, [1e-3, 2], log scale in a fit).

Why a fourth: on MERL's brass and hematite, ggx3 under the log loss ends just short
of the sphere's visible line (20.0 and 19.0 dB); a fourth lobe reads visible on both
(20.3 and 22.7 dB). It contains ggx3 (``ks4 = 0``) and is fitted from ggx3's optimum
as ggx3 is from ggx2's; no renderer's material (exported by a refit). The lobes are
not ordered by width after a fit: any of them may end the sharpest.
"""

from __future__ import annotations

from .base import KD, ParamSpec
from .ggx2 import ALPHA1, ALPHA2, KS1, KS2, lobe_grid, new_lobe_scan
from .ggx3 import ALPHA3, GGX3, KS3
from .microfacet import F0

KS4 = ParamSpec("ks4", "scale of the fourth lobe (RGB)", 0.0, None, rgb=True)
ALPHA4 = ParamSpec("alpha4", "roughness of the fourth lobe", 1e-3, 2.0, scale="log")


class GGX4(GGX3):
    name = "ggx4"
    param_specs = (KD, KS1, ALPHA1, KS2, ALPHA2, KS3, ALPHA3, KS4, ALPHA4, F0)
    lobe_scales = ("ks1", "ks2", "ks3", "ks4")
    lobe_alphas = ("alpha1", "alpha2", "alpha3", "alpha4")
    shape_grid = lobe_grid(lobe_alphas)
    parent = "ggx3"
    parent_scan = new_lobe_scan(lobe_scales[-1], lobe_alphas[-1])
