"""glTF 2.0 metallic-roughness with a clear coat (``KHR_materials_clearcoat``), as the
extension's text defines it.

``gltf_clearcoat``: the core material (``gltf_pbr``, Appendix B) under a clear,
colourless coat of index 1.5. The extension's layering (its "Implementation" section,
with the coat's normal the surface's):

    fc        = 0.04 + (1 - 0.04) (1 - |V.N|)^5          (the coat's Fresnel, of the VIEW)
    coat_brdf = D(a_c) G(a_c) / (4 |V.N| |L.N|),  a_c = clearcoatRoughness^2
    f         = mix(material, coat_brdf, clearcoat * fc)
              = (1 - clearcoat fc) material + clearcoat fc coat_brdf

``coat_brdf`` is Appendix B's specular term without its Fresnel (white GGX, separable
Smith: ``brdffit.models.renderer_terms.separable_ggx_dg``, the lobe ``gltf_pbr``
shades with). The Fresnel weight reads the view's angle to the normal, not the half
vector's, so the model is not reciprocal: it is the extension's, and a fit of it
exported to glTF (``brdffit.export.gltf``, five factors copied) is the material the
extension defines.

| name                | range              | meaning                                       |
|---------------------|--------------------|-----------------------------------------------|
| base_color          | [0, 1], RGB        | ``baseColorFactor`` (linear RGB)              |
| metallic            | [0, 1]             | ``metallicFactor``                            |
| roughness           | [0.0316, 1] (log)  | ``roughnessFactor``                           |
| clearcoat           | [0, 1]             | ``clearcoatFactor``: the coat's weight        |
| clearcoat_roughness | [0.0316, 1] (log)  | ``clearcoatRoughnessFactor`` (alpha = r^2)    |

At ``clearcoat = 0`` the material is ``gltf_pbr``'s exactly: a fit starts from the
``gltf_pbr`` fit with the coat off (``parent``), so it never ends worse than it.
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from .base import Params, ParamSpec
from .frame import Frame
from .gltf_blender import SPECULAR_IOR
from .gltf_layer import BLENDER_BASE, THREEJS_BASE, GltfLayer
from .gltf_pbr import BASE_COLOR, DIELECTRIC_F0, METALLIC, ROUGHNESS
from .gltf_threejs import MIN_ROUGHNESS, ggx_vd, threejs_fresnel
from .microfacet import dielectric_fresnel
from .renderer_terms import gtr1_d, separable_ggx_dg, separable_smith_denominator

CLEARCOAT = ParamSpec("clearcoat", "clearcoatFactor: the clear coat's weight", 0.0, 1.0)
CLEARCOAT_ROUGHNESS = ParamSpec(
    "clearcoat_roughness", "clearcoatRoughnessFactor (the coat's alpha = its square)",
    math.sqrt(1e-3), 1.0, scale="log")

#: The coat's roughness values a fit starts from: a coat is sharper than the base
#: (alpha 0.002 .. 0.04), or it would be one lobe twice.
COAT_ROUGHNESS_STARTS = (0.045, 0.1, 0.2)



class GltfClearcoat(GltfLayer):
    name = "gltf_clearcoat"
    param_specs = (BASE_COLOR, METALLIC, ROUGHNESS, CLEARCOAT, CLEARCOAT_ROUGHNESS)
    layer_params = {"clearcoat": ("clearcoat", ("clearcoat_roughness",))}
    #: a half-weight coat of each roughness
    layer_starts = tuple({"clearcoat": 0.5, "clearcoat_roughness": r}
                         for r in COAT_ROUGHNESS_STARTS)

    def embed_parent(self, parent_params: dict) -> dict:
        """The ``gltf_pbr`` fit with the coat off (clearcoat 0) and sharp, ready to grow."""
        return {**parent_params, "clearcoat": 0.0, "clearcoat_roughness": 0.1}

    def eval_channels(self, params: Params, frame: Frame):
        base = self.base_model.eval_channels(params, frame)
        cr = params["clearcoat_roughness"]
        coat = separable_ggx_dg(cr * cr, frame.cos_h, frame.sin2_h, frame.cos_i,
                                frame.sin2_i, frame.cos_o, frame.sin2_o)
        view = jnp.clip(1.0 - jnp.abs(frame.cos_o), 0.0, 1.0)
        weight = params["clearcoat"] * (DIELECTRIC_F0 + (1.0 - DIELECTRIC_F0) * view**5)
        return (1.0 - weight)[None] * base + (weight * coat)[None]


class GltfThreejsClearcoat(GltfClearcoat):
    """A ``KHR_materials_clearcoat`` file as three.js r187 shades it for a direct light
    (``BRDF_GGX_Clearcoat``, ``RE_Direct_Physical``, meshphysical's output), the same
    five parameters:

        f = (1 - clearcoat Fc(cos_o)) f_threejs + clearcoat Fc(v.h) V D(max(cr, 0.045))

    with ``Fc(x) = 0.04 + 0.96 Fs(x)`` (three.js's exp2 Schlick), V and D three.js's
    height-correlated Smith and GGX, and ``f_threejs`` the base as three.js shades it
    (``gltf_threejs``). The spec (``gltf_clearcoat``) weights an unshadowed coat lobe by
    the Fresnel at the view's angle alone; three.js puts the Fresnel at v.h inside the
    coat's BRDF and takes the view's for the base's attenuation. What a coat export's
    ``fidelity.viewers["threejs"]`` is measured with (tests/test_export_viewers.py
    checks it against three.js's render of the file)."""

    name = "gltf_threejs_clearcoat"
    parent = "gltf_threejs"
    base_model = THREEJS_BASE

    def eval_channels(self, params: Params, frame: Frame):
        base = self.base_model.eval_channels(params, frame)
        cc = params["clearcoat"]
        r = jnp.clip(params["clearcoat_roughness"], MIN_ROUGHNESS, 1.0)
        lobe = ggx_vd(r, frame.cos_i, frame.cos_o, frame.cos_h)
        coat_fresnel = threejs_fresnel(DIELECTRIC_F0, frame.cos_d)
        view_fresnel = threejs_fresnel(DIELECTRIC_F0, frame.cos_o)
        return (1.0 - cc * view_fresnel)[None] * base + (cc * coat_fresnel * lobe)[None]


#: Cycles' fixed roughness of the clear coat's shadowing (Disney's 0.25).
BLENDER_COAT_G_ALPHA = 0.25
#: Cycles' weight of Principled v1's clear coat lobe per unit of Clearcoat (Disney's).
BLENDER_COAT_WEIGHT = 0.25


class GltfBlenderClearcoat(GltfClearcoat):
    """A ``KHR_materials_clearcoat`` file as Blender 3.4 shades it: its importer sets
    the Principled BSDF's (v1) Clearcoat and Clearcoat Roughness to the two factors,
    and Cycles adds Disney's coat lobe (``svm_node_closure_bsdf``,
    ``bsdf_microfacet_ggx_clearcoat``) to the base without dimming it:

        f = f_blender + 0.25 clearcoat F(v.h) D_GTR1(cos_h; cr^2) G1(wi) G1(wo) / (4 cos_i cos_o)

    with ``F`` the exact dielectric Fresnel at index 1.5, ``D_GTR1`` Burley's
    (:func:`gtr1_d`) and ``G1`` separable Smith GGX at Disney's fixed 0.25. The spec's
    coat at the same factors is a GGX lobe of 4x the weight that dims the base by its
    Fresnel; Blender's is a quarter as strong, with GTR1's long tail. What a coat
    export's ``fidelity.viewers["blender"]`` is measured with
    (tests/test_export_blender.py checks it against Cycles' render of the file)."""

    name = "gltf_blender_clearcoat"
    parent = "gltf_blender"
    base_model = BLENDER_BASE

    def eval_channels(self, params: Params, frame: Frame):
        base = self.base_model.eval_channels(params, frame)
        # Cycles' GTR1 alpha is the Clearcoat Roughness squared (its render: with the
        # roughness itself the model was 2% brighter than Cycles at the median pixel)
        alpha = params["clearcoat_roughness"] ** 2
        shadowing = separable_smith_denominator(BLENDER_COAT_G_ALPHA, frame.cos_i,
                                                frame.sin2_i, frame.cos_o, frame.sin2_o)
        coat = (BLENDER_COAT_WEIGHT * params["clearcoat"]
                * dielectric_fresnel(SPECULAR_IOR, frame.cos_d)
                * gtr1_d(alpha, frame.cos_h) / shadowing)
        return base + coat[None]
