"""glTF 2.0 metallic-roughness BRDF (glTF 2.0 spec, Appendix B), separable Smith GGX.

    c_diff = base_color (1 - metallic),   f0 = 0.04 (1 - metallic) + base_color metallic
    alpha  = roughness^2
    F      = f0 + (1 - f0) (1 - cos_d)^5                       (RGB)
    f      = (1 - F) c_diff / pi + F D G1(wi) G1(wo) / (4 cos_i cos_o)

D and G1 are the GGX terms of ``brdffit.models.renderer_terms``; 0.04 is the
reflectance of the default glTF index of refraction 1.5 (``((1.5 - 1)/(1.5 + 1))^2``).
A fit of this model *is* a glTF material: its export (``brdffit.export.gltf``) copies
the three parameters and loses nothing.

| name       | range              | meaning                                        |
|------------|--------------------|------------------------------------------------|
| base_color | [0, 1], RGB        | ``baseColorFactor`` (linear RGB)               |
| metallic   | [0, 1]             | ``metallicFactor``                             |
| roughness  | [0.0316, 1] (log)  | ``roughnessFactor``; lower bound: alpha = 1e-3 |
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from .base import AbstractBRDFModel, Params, ParamSpec
from .frame import Frame
from .microfacet import ALPHA_GRID
from .renderer_terms import separable_ggx_dg

#: Schlick reflectance of a dielectric at glTF's default ior 1.5.
DIELECTRIC_F0 = 0.04

BASE_COLOR = ParamSpec("base_color", "baseColorFactor, linear RGB", 0.0, 1.0, rgb=True)
METALLIC = ParamSpec("metallic", "metallicFactor", 0.0, 1.0)
ROUGHNESS = ParamSpec(
    "roughness", "roughnessFactor (alpha = roughness^2)", math.sqrt(1e-3), 1.0, scale="log"
)


class GltfPBR(AbstractBRDFModel):
    name = "gltf_pbr"
    param_specs = (BASE_COLOR, METALLIC, ROUGHNESS)
    shape_grid = tuple(
        {"roughness": min(math.sqrt(a), 1.0), "metallic": m}
        for a in ALPHA_GRID
        for m in (0.0, 0.5, 1.0)
    )

    def eval_channels(self, params: Params, frame: Frame):
        base = params["base_color"]
        m = params["metallic"]
        rough = params["roughness"]
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        base = base[expand]
        f0 = DIELECTRIC_F0 * (1.0 - m) + base * m
        c_diff = base * (1.0 - m)
        fresnel = f0 + (1.0 - f0) * (1.0 - frame.cos_d)[None] ** 5
        dg = separable_ggx_dg(
            rough * rough, frame.cos_h, frame.sin2_h,
            frame.cos_i, frame.sin2_i, frame.cos_o, frame.sin2_o,
        )
        return (1.0 - fresnel) * c_diff / jnp.pi + fresnel * dg[None]

    def eval_frame(self, params: Params, frame: Frame):
        return jnp.moveaxis(self.eval_channels(params, frame), 0, -1)

    def start_candidates(self, table, usable: np.ndarray, kd: np.ndarray) -> np.ndarray:
        """Unconstrained starts, one per (roughness, metallic) on ``shape_grid``.

        A dielectric start takes the diffuse estimate as its base colour; a metal's
        base colour is its highlight colour, the peak bin's, normalised to 0.9.
        """
        from brdffit.fitting.starts import peak_bin

        peak = table.rgb.reshape(3, -1)[:, peak_bin(table, usable)]
        metal = 0.9 * peak / max(float(np.max(peak)), 1e-12)
        starts = []
        for shape in self.shape_grid:
            m = shape["metallic"]
            base = np.clip((1 - m) * kd + m * metal, 0.02, 0.98)
            starts.append(self.unconstrain({"base_color": base, **shape}))
        return np.stack(starts)
