"""Mitsuba 3 rough conductor, complex IOR per channel, blended with a diffuse base.

    f = (1 - weight) F_c(cos_d; eta, k) D G1(wi) G1(wo) / (4 cos_i cos_o) + weight kd / pi

the ``blendbsdf`` of Mitsuba 3's ``roughconductor`` (``distribution="ggx"``, its
separable Smith G1 and its conductor Fresnel F_c, ``brdffit.models.renderer_terms``)
and a ``diffuse`` of reflectance ``kd``, with the blend ``weight``. ``weight = 0`` is
a pure metal. Each term is a renderer plugin's own formula, so the export
(``brdffit.export.mitsuba``) is exact, and the material conserves energy by
construction (both plugins do, and the blend is convex).

| name   | range             | meaning                                             |
|--------|-------------------|-----------------------------------------------------|
| eta    | [0.02, 10] (log), RGB | real part of the conductor's index (Mitsuba ``eta``) |
| k      | [0, 15], RGB      | imaginary part, absorption (Mitsuba ``k``)          |
| alpha  | [1e-3, 2] (log)   | GGX roughness (Mitsuba ``alpha``)                   |
| kd     | [0, 1], RGB       | diffuse reflectance (Mitsuba ``diffuse.reflectance``) |
| weight | [0, 1]            | blend weight of the diffuse base (``blendbsdf.weight``) |
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .base import AbstractBRDFModel, Params, ParamSpec
from .frame import Frame
from .microfacet import ALPHA, ALPHA_GRID
from .renderer_terms import conductor_fresnel, separable_ggx_dg

ETA = ParamSpec("eta", "real part of the complex index of refraction, RGB", 0.02, 10.0,
                rgb=True, scale="log")
K = ParamSpec("k", "imaginary part (absorption) of the complex index, RGB", 0.0, 15.0, rgb=True)
REFLECTANCE = ParamSpec("kd", "diffuse reflectance, RGB", 0.0, 1.0, rgb=True)
WEIGHT = ParamSpec("weight", "blend weight of the diffuse base", 0.0, 1.0)

#: (eta, k) at R, G, B of metals a fit starts from (linear sRGB primaries, Mitsuba's
#: spectral data reduced to RGB): gold, copper, aluminium, chromium, silver; and a
#: dielectric (eta 1.5, k 0) for a material that is not a metal at all.
METAL_STARTS = (
    ((0.143, 0.374, 1.442), (3.983, 2.385, 1.603)),
    ((0.200, 0.924, 1.102), (3.912, 2.452, 2.142)),
    ((1.657, 0.880, 0.521), (9.224, 6.270, 4.837)),
    ((3.180, 3.180, 2.010), (3.300, 3.300, 3.350)),
    ((0.155, 0.117, 0.138), (4.828, 3.122, 2.147)),
    ((1.5, 1.5, 1.5), (0.0, 0.0, 0.0)),
)


class RoughConductor(AbstractBRDFModel):
    name = "rough_conductor"
    param_specs = (ETA, K, ALPHA, REFLECTANCE, WEIGHT)
    shape_grid = tuple(
        {"alpha": a, "eta": np.array(eta), "k": np.array(k)}
        for a in ALPHA_GRID
        for eta, k in METAL_STARTS
    )

    def eval_channels(self, params: Params, frame: Frame):
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        fresnel = conductor_fresnel(params["eta"][expand], params["k"][expand], frame.cos_d[None])
        dg = separable_ggx_dg(
            params["alpha"], frame.cos_h, frame.sin2_h,
            frame.cos_i, frame.sin2_i, frame.cos_o, frame.sin2_o,
        )
        w = params["weight"]
        return (1.0 - w) * fresnel * dg[None] + w * params["kd"][expand] / jnp.pi

    def eval_frame(self, params: Params, frame: Frame):
        return jnp.moveaxis(self.eval_channels(params, frame), 0, -1)

    def start_candidates(self, table, usable: np.ndarray, kd: np.ndarray) -> np.ndarray:
        """Unconstrained starts, one per (alpha, metal) on ``shape_grid``.

        The diffuse estimate ``kd`` (a reflectance, pi f) is split into a blend weight
        just above its largest channel and a reflectance ``kd / weight`` <= 1.
        """
        weight = float(np.clip(1.25 * np.max(kd), 0.01, 0.9))
        refl = np.clip(kd / weight, 0.0, 0.98)
        return np.stack([
            self.unconstrain({**shape, "kd": refl, "weight": weight}) for shape in self.shape_grid
        ])
