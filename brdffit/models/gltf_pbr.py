"""glTF 2.0 metallic-roughness BRDF (glTF 2.0 spec, Appendix B), separable Smith GGX.

``gltf_pbr``: the core material. ``gltf_pbr_ior`` (``GltfPBR(ior=True)``): the same with
the extension ``KHR_materials_ior``, whose ``ior`` sets the dielectric reflectance
``((ior - 1)/(ior + 1))^2`` in place of 0.04 (the metal part is unchanged).

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
| ior        | [1, 3]             | ``KHR_materials_ior.ior`` (``gltf_pbr_ior`` only) |
"""

from __future__ import annotations

import math

import equinox as eqx
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

IOR = ParamSpec("ior", "KHR_materials_ior: index of refraction of the dielectric", 1.0, 3.0)
#: glTF's default index of refraction (its f0 is DIELECTRIC_F0).
DEFAULT_IOR = 1.5


class GltfPBR(AbstractBRDFModel):
    #: True: ``gltf_pbr_ior``, the dielectric's index a parameter (KHR_materials_ior).
    ior: bool = eqx.field(static=True, default=False)

    @property
    def name(self) -> str:
        return "gltf_pbr_ior" if self.ior else "gltf_pbr"

    @property
    def param_specs(self) -> tuple[ParamSpec, ...]:
        return (BASE_COLOR, METALLIC, ROUGHNESS) + ((IOR,) if self.ior else ())

    @property
    def shape_grid(self) -> tuple[dict[str, float], ...]:
        extra = {"ior": DEFAULT_IOR} if self.ior else {}
        return tuple(
            {"roughness": min(math.sqrt(a), 1.0), "metallic": m, **extra}
            for a in ALPHA_GRID
            for m in (0.0, 0.5, 1.0)
        )

    @property
    def parent(self) -> str | None:
        # gltf_pbr is gltf_pbr_ior at ior 1.5: seeded from its optimum, the larger
        # model never ends worse (a start at ior 1.5 alone did, on blue-metallic-paint)
        return "gltf_pbr" if self.ior else None

    def embed_parent(self, parent_params: dict) -> dict:
        if not self.ior:
            return super().embed_parent(parent_params)
        return {**parent_params, "ior": DEFAULT_IOR}

    def dielectric_f0(self, params: Params):
        if not self.ior:
            return DIELECTRIC_F0
        r = (params["ior"] - 1.0) / (params["ior"] + 1.0)
        return r * r

    def eval_channels(self, params: Params, frame: Frame):
        base = params["base_color"]
        m = params["metallic"]
        rough = params["roughness"]
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        base = base[expand]
        f0 = self.dielectric_f0(params) * (1.0 - m) + base * m
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
        from brdffit.io.grid import peak_bin

        peak = table.rgb.reshape(3, -1)[:, peak_bin(table, usable)]
        metal = 0.9 * peak / max(float(np.max(peak)), 1e-12)
        starts = []
        for shape in self.shape_grid:
            m = shape["metallic"]
            base = np.clip((1 - m) * kd + m * metal, 0.02, 0.98)
            starts.append(self.unconstrain({"base_color": base, **shape}))
        return np.stack(starts)
