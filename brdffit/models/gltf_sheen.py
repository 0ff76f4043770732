"""glTF 2.0 metallic-roughness with a sheen (``KHR_materials_sheen``), the sheen as
three.js shades it for a direct light.

``gltf_sheen``: the core material (``gltf_pbr``, Appendix B) under a layer of fibres
that reflect towards grazing angles (velvet, felt, satin). The extension fixes the
layering and leaves the sheen's BRDF to the implementation ("Implementations of the
BRDF itself can vary"; its formulas are a non-normative note): the sheen here is
three.js r187's (``BRDF_Sheen``, ``IBLSheenBRDF`` and ``RE_Direct_Physical`` of its
ShaderChunk ``lights_physical_pars_fragment``), the viewer most glTF files are opened
in:

    a       = sheenRoughness^2                     (as three.js and Khronos's Sample
                                                    Viewer do; the note's text has a = r)
    D       = (2 + 1/a) s^(1/(2a)) / (2 pi),  s = max(sin^2 theta_h, 2^-7)
                                               (Conty-Kulla "Charlie"; the floor is three.js's)
    V       = min(1, 1 / (4 (cos_i + cos_o - cos_i cos_o)))    (Neubelt, the note's
                                                               "simpler visibility")
    E(x)    = min(1, exp(A(r) x + B(r)))       (three.js's fit of the sheen's albedo)
    scale   = 1 - max(sheenColor) max(E(cos_o), E(cos_i))     (the note's albedo scaling)
    f       = sheenColor D V + scale material

with A, B the quadratics in r of :func:`sheen_albedo`. At ``sheen_color = 0`` the
material is ``gltf_pbr``'s exactly (scale 1, no sheen): a fit starts from the
``gltf_pbr`` fit with the sheen off (``parent``), so it never ends worse than it.
``tests/test_layered_models.py`` checks the sheen against three.js's own render of
the exported file.

| name            | range              | meaning                                       |
|-----------------|--------------------|-----------------------------------------------|
| base_color      | [0, 1], RGB        | ``baseColorFactor`` (linear RGB)              |
| metallic        | [0, 1]             | ``metallicFactor``                            |
| roughness       | [0.0316, 1] (log)  | ``roughnessFactor``                           |
| sheen_color     | [0, 1], RGB        | ``sheenColorFactor`` (linear RGB)             |
| sheen_roughness | [0.1, 1] (log)     | ``sheenRoughnessFactor`` (alpha = its square) |
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .base import Params, ParamSpec
from .frame import Frame
from .gltf_layer import BLENDER_BASE, THREEJS_BASE, GltfLayer
from .gltf_pbr import BASE_COLOR, METALLIC, ROUGHNESS
from .renderer_terms import ashikhmin_velvet

SHEEN_COLOR = ParamSpec("sheen_color", "sheenColorFactor, linear RGB", 0.0, 1.0, rgb=True)
#: The sheen's least roughness, 0.1 (alpha 0.01): the fibres' lobe then still spans
#: ~8 degrees of theta_h below 90, several of the MERL grid's coarse bins there. At
#: glTF's own floor (0.0316, as the other roughnesses here) a fit put a 2-degree spike
#: on one or two grazing bins of a phenolic's noise (-1.7 dB on its render).
SHEEN_ROUGHNESS = ParamSpec(
    "sheen_roughness", "sheenRoughnessFactor (the fibres' alpha = its square)",
    0.1, 1.0, scale="log")

#: three.js's floor of sin^2 theta_h in D (``D_Charlie``: 2^-7, so that its square
#: stays above zero in half precision). It also keeps D's power finite at the normal.
SIN2_H_FLOOR = 2.0**-7
#: The sheen's roughness and colour a fit starts from (beside the base's fit with
#: the sheen off): fibres from sharp to broad, a grey sheen of moderate strength.
SHEEN_ROUGHNESS_STARTS = (0.3, 0.6, 0.9)
SHEEN_COLOR_START = 0.3



def charlie_d(alpha, sin2_h):
    """Conty and Kulla's "Charlie" distribution of fibre normals, three.js's floor."""
    s = jnp.maximum(sin2_h, SIN2_H_FLOOR)
    return (2.0 + 1.0 / alpha) * jnp.exp(jnp.log(s) * (0.5 / alpha)) / (2.0 * jnp.pi)


def neubelt_v(cos_i, cos_o):
    """Neubelt and Pettineo's visibility, saturated as three.js does (``V_Neubelt``):
    ``min(1, 1/(4 (cos_i + cos_o - cos_i cos_o)))``, 1 at grazing on both sides."""
    return 0.25 / jnp.maximum(cos_i + cos_o - cos_i * cos_o, 0.25)


def sheen_albedo(roughness, cos):
    """three.js's curve fit of the sheen's directional albedo (``IBLSheenBRDF``), of the
    sheen's roughness (not squared) and the cosine to the normal."""
    r = roughness
    r_inv = 1.0 / (r + 0.1)
    a = -1.9362 + 1.0678 * r + 0.4573 * r * r - 0.8469 * r_inv
    b = -0.6014 + 0.5538 * r - 0.4670 * r * r - 0.1255 * r_inv
    return jnp.minimum(jnp.exp(a * cos + b), 1.0)


def sheen_layer(sheen_color, sheen_roughness, frame: Frame):
    """The sheen's BRDF (3, ...) and the scale (...) it leaves the base, for
    ``sheen_color`` (3,) and ``sheen_roughness`` (a scalar)."""
    expand = (slice(None),) + (None,) * frame.cos_i.ndim
    r = sheen_roughness
    lobe = charlie_d(r * r, frame.sin2_h) * neubelt_v(frame.cos_i, frame.cos_o)
    albedo = jnp.maximum(sheen_albedo(r, frame.cos_o), sheen_albedo(r, frame.cos_i))
    scale = 1.0 - jnp.max(sheen_color) * albedo
    return sheen_color[expand] * lobe[None], scale


class GltfSheen(GltfLayer):
    name = "gltf_sheen"
    param_specs = (BASE_COLOR, METALLIC, ROUGHNESS, SHEEN_COLOR, SHEEN_ROUGHNESS)
    layer_params = {"sheen": ("sheen_color", ("sheen_roughness",))}
    #: a grey sheen of moderate strength, fibres from sharp to broad
    layer_starts = tuple({"sheen_color": SHEEN_COLOR_START, "sheen_roughness": r}
                         for r in SHEEN_ROUGHNESS_STARTS)

    def embed_parent(self, parent_params: dict) -> dict:
        """The ``gltf_pbr`` fit with the sheen off (black), ready to grow."""
        return {**parent_params, "sheen_color": np.zeros(3), "sheen_roughness": 0.6}

    def eval_channels(self, params: Params, frame: Frame):
        base = self.base_model.eval_channels(params, frame)
        sheen, scale = sheen_layer(params["sheen_color"], params["sheen_roughness"], frame)
        return sheen + scale[None] * base


class GltfThreejsSheen(GltfSheen):
    """A ``KHR_materials_sheen`` file as three.js shades it: the same five parameters,
    the sheen (:func:`sheen_layer`, three.js's) over three.js's own shading of the core
    factors (``gltf_threejs``: its roughness floor, Fresnel, height-correlated V and
    multiple-scattering compensation) instead of the spec's:

        f = sheenColor D V + scale f_threejs(base_color, metallic, roughness)

    What ``fidelity.viewers["threejs"]`` judges a sheen export by;
    ``tests/test_export_viewers.py`` checks it against three.js's render of the file.
    Its fit starts from ``gltf_threejs``'s with the sheen off, as ``gltf_sheen``'s
    from ``gltf_pbr``'s."""

    name = "gltf_threejs_sheen"
    parent = "gltf_threejs"
    base_model = THREEJS_BASE


class GltfBlenderSheen(GltfSheen):
    """A ``KHR_materials_sheen`` file as Blender 3.4 shades it: its importer adds a
    Velvet BSDF (Color the sheen colour, Sigma the sheen roughness) to the Principled
    BSDF (an Add Shader; ``gltf2_blender_pbrMetallicRoughness``), and Cycles shades it
    as Ashikhmin's velvet (``renderer_terms.ashikhmin_velvet``), with no albedo scaling
    of the base:

        f = f_blender + sheen_color f_velvet(sheen_roughness)

    What a sheen export's ``fidelity.viewers["blender"]`` is measured with
    (tests/test_export_blender.py checks it against Cycles' render of the file)."""

    name = "gltf_blender_sheen"
    parent = "gltf_blender"
    base_model = BLENDER_BASE

    def eval_channels(self, params: Params, frame: Frame):
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        base = self.base_model.eval_channels(params, frame)
        velvet = ashikhmin_velvet(params["sheen_roughness"], frame.cos_i, frame.cos_o,
                                  frame.cos_h, frame.sin2_h, frame.cos_d)
        return base + params["sheen_color"][expand] * velvet[None]
