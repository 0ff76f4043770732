"""glTF 2.0 metallic-roughness BRDF as the spec defines it (Appendix B), separable Smith GGX.

``gltf_pbr``: the core material. ``gltf_pbr_ior`` (``GltfPBR(ior=True)``): the same with
the extension ``KHR_materials_ior``, whose ``ior`` sets the dielectric reflectance
``((ior - 1)/(ior + 1))^2`` in place of 0.04 (the metal part is unchanged).

The spec defines the material as a mix of two BRDFs (Appendix B, "Complete model"):

    alpha      = roughness^2,  c = |v.h| (= cos_d),  s = (1 - c)^5
    specular   = D G1(wi) G1(wo) / (4 cos_i cos_o)                (white, GGX, separable Smith)
    dielectric = mix(base_color / pi, specular, F_d),  F_d = f0_d + (1 - f0_d) s,  f0_d = 0.04
    metal      = specular F_m,                          F_m = base_color + (1 - base_color) s
    f          = mix(dielectric, metal, metallic)

Its Appendix B also gives an "implementation" in pseudocode that lerps one Fresnel
from ``f0 = mix(0.04, base_color, metallic)`` and weights the diffuse by ``1 - F``
(:func:`pseudocode_channels`). Schlick's F is linear in f0, so the two agree on the
specular term exactly; the diffuse agrees only at metallic 0 or 1: between, the
pseudocode dims it by the metal's Fresnel too (1.5-2.2x less diffuse at metallic
0.73 on a bright base; a known erratum of the pseudocode, glTF issue 2386). This model
is the definition, the spec's normative text: a fit of it exported to glTF
(``brdffit.export.gltf``, a copy of the three parameters) is the material the spec
defines, with nothing lost.
D and G1 are the GGX terms of ``brdffit.models.renderer_terms``; 0.04 is the
reflectance of the default glTF index of refraction 1.5 (``((1.5 - 1)/(1.5 + 1))^2``).

| name       | range              | meaning                                        |
|------------|--------------------|------------------------------------------------|
| base_color | [0, 1], RGB        | ``baseColorFactor`` (linear RGB)               |
| metallic   | [0, 1]             | ``metallicFactor``                             |
| roughness  | [0.0316, 1] (log)  | ``roughnessFactor``; lower bound: alpha = 1e-3 |
| ior        | [1, 3]             | ``KHR_materials_ior.ior`` (``gltf_pbr_ior`` only) |

``gltf_pbr_dielectric`` (``GltfPBR(dielectric=True)``): metallic held at 0, the
other two parameters as above: a dielectric, the glTF export's alternative to a
metal mixture (``brdffit.export.gltf``).
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
    #: True: ``gltf_pbr_dielectric``, metallic held at 0 (not a parameter): the glTF
    #: export's dielectric alternative to a metal mixture (brdffit.export.gltf).
    dielectric: bool = eqx.field(static=True, default=False)

    @property
    def name(self) -> str:
        return ("gltf_pbr_dielectric" if self.dielectric
                else "gltf_pbr_ior" if self.ior else "gltf_pbr")

    @property
    def param_specs(self) -> tuple[ParamSpec, ...]:
        if self.dielectric:
            return (BASE_COLOR, ROUGHNESS)
        return (BASE_COLOR, METALLIC, ROUGHNESS) + ((IOR,) if self.ior else ())

    @property
    def shape_grid(self) -> tuple[dict[str, float], ...]:
        extra = {"ior": DEFAULT_IOR} if self.ior else {}
        metallic = (None,) if self.dielectric else (0.0, 0.5, 1.0)
        return tuple(
            {"roughness": min(math.sqrt(a), 1.0), **({} if m is None else {"metallic": m}),
             **extra}
            for a in ALPHA_GRID
            for m in metallic
        )

    @property
    def start_family(self) -> str | None:
        # a metal and a dielectric explain a highlight differently, as standard_surface's
        # metalness: the best-scored start alone ended in the dielectric's basin on
        # near-mirror metals (chrome: a dark dielectric, log_rmse 0.0184 against the
        # metal's 0.0146; aluminium, tungsten-carbide, and a metal's own exact truth)
        return None if self.dielectric else "metallic"

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
        return self.mixed_channels(params, self._terms(params, frame))

    def mixed_channels(self, params: Params, terms):
        """The material (3, ...) from :meth:`_terms` (a layer over it takes the terms
        once, for the base and for itself)."""
        base, m, dg, s = terms
        f0_d = self.dielectric_f0(params)
        fresnel_d = f0_d + (1.0 - f0_d) * s  # the dielectric's, colourless
        fresnel_m = base + (1.0 - base) * s  # the metal's, coloured by base_color
        dielectric = (1.0 - fresnel_d) * base / jnp.pi + fresnel_d * dg
        return (1.0 - m) * dielectric + m * fresnel_m * dg

    def pseudocode_channels(self, params: Params, frame: Frame):
        """Appendix B's implementation pseudocode, (3, ...): one Fresnel from the
        lerped f0 weights the diffuse by ``1 - F``. Not this model: what a renderer
        that follows the pseudocode shows for the same parameters."""
        base, m, dg, s = self._terms(params, frame)
        f0 = self.dielectric_f0(params) * (1.0 - m) + base * m
        fresnel = f0 + (1.0 - f0) * s
        return (1.0 - fresnel) * base * (1.0 - m) / jnp.pi + fresnel * dg

    def _terms(self, params: Params, frame: Frame):
        """base_color (3, 1...), metallic, the white lobe D V and Schlick's (1 - c)^5."""
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        rough = params["roughness"]
        dg = separable_ggx_dg(
            rough * rough, frame.cos_h, frame.sin2_h,
            frame.cos_i, frame.sin2_i, frame.cos_o, frame.sin2_o,
        )
        metallic = 0.0 if self.dielectric else params["metallic"]
        return params["base_color"][expand], metallic, dg[None], \
            ((1.0 - frame.cos_d) ** 5)[None]

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
            m = shape.get("metallic", 0.0)
            base = np.clip((1 - m) * kd + m * metal, 0.02, 0.98)
            starts.append(self.unconstrain({"base_color": base, **shape}))
        return np.stack(starts)
