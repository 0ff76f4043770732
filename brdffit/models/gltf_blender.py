"""A glTF material as Blender shades it for a direct light: ``gltf_blender``.

The same three parameters as ``gltf_pbr`` (``base_color``, ``metallic``, ``roughness``:
the file's factors). Blender 3.4's glTF importer maps them to a Principled BSDF (v1) at
its defaults otherwise (Specular 0.5, Specular Tint 0, Sheen 0, Clearcoat 0,
distribution GGX; it ignores ``KHR_materials_ior``), which Cycles evaluates as two
closures (``svm_node_closure_bsdf``, ``bsdf_principled_diffuse``,
``bsdf_microfacet``):

    diffuse  = (1 - metallic) base_color / pi
               [(1 - Fv/2)(1 - Fl/2) + RR (Fl + Fv + Fl Fv (RR - 1))]
               Fl = (1 - cos_i)^5, Fv = (1 - cos_o)^5, RR = 2 roughness cos_d^2
                                    (Burley's diffuse with its retro-reflection)
    cspec0   = mix(0.08 Specular, base_color, metallic) = mix(0.04, base_color, metallic)
    F        = cspec0 + (1 - cspec0) (F_d(cos_d; 1.5) - 0.04) / (1 - 0.04)
               (the exact dielectric Fresnel of the Specular's index, 1.5, rescaled)
    specular = F D G1(wi) G1(wo) / (4 cos_i cos_o),  alpha = roughness^2  (separable)
    f        = diffuse + specular

What differs from the spec's definition (``gltf_pbr``): the dielectric's diffuse is
Burley's, not weighted by ``1 - F`` (a red dielectric renders 4% brighter at the
centre of the preview sphere), and the Fresnel's shape. ``tests/test_export_blender.py``
checks the model against Cycles' render of the exported file, pixel by pixel.

| name       | range              | meaning                                        |
|------------|--------------------|------------------------------------------------|
| base_color | [0, 1], RGB        | ``baseColorFactor`` (linear RGB): Base Color   |
| metallic   | [0, 1]             | ``metallicFactor``: Metallic                   |
| roughness  | [0.0316, 1] (log)  | ``roughnessFactor``: Roughness                 |
"""

from __future__ import annotations

import jax.numpy as jnp

from .base import Params
from .frame import Frame
from .gltf_pbr import DIELECTRIC_F0, GltfPBR
from .microfacet import dielectric_fresnel
from .renderer_terms import burley_diffuse, separable_ggx_dg

#: The index Cycles derives from the Principled BSDF's Specular 0.5 (the importer's):
#: 2 / (1 - sqrt(0.08 Specular)) - 1.
SPECULAR_IOR = 1.5


class GltfBlender(GltfPBR):
    """``gltf_pbr``'s parameters as Blender's Cycles shades them (module docstring)."""

    @property
    def name(self) -> str:
        return "gltf_blender"

    @property
    def parent(self) -> str | None:
        return None

    def eval_channels(self, params: Params, frame: Frame):
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        base, m, r = params["base_color"][expand], params["metallic"], params["roughness"]
        burley = burley_diffuse(r, frame.cos_i, frame.cos_o, frame.cos_d)
        diffuse = (1.0 - m) * base / jnp.pi * burley[None]
        cspec0 = DIELECTRIC_F0 * (1.0 - m) + base * m
        fh = ((dielectric_fresnel(SPECULAR_IOR, frame.cos_d) - DIELECTRIC_F0)
              / (1.0 - DIELECTRIC_F0))[None]
        dg = separable_ggx_dg(r * r, frame.cos_h, frame.sin2_h,
                              frame.cos_i, frame.sin2_i, frame.cos_o, frame.sin2_o)
        return diffuse + (cspec0 * (1.0 - fh) + fh) * dg[None]
