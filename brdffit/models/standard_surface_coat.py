"""MaterialX standard_surface with its clear coat, as its GLSL shades it:
``standard_surface_coat``.

The ``standard_surface`` node (``standard_surface``, this package) under the coat of its
nodegraph (``NG_standard_surface_surfaceshader_100``): a ``dielectric_bsdf`` of weight
``coat``, white tint, index ``coat_IOR`` and roughness ``coat_roughness``, layered over
the rest (``coat_layer``: ``mx_layer_bsdf``, ``top.response + base.response *
top.throughput``), the rest multiplied by ``coat_attenuation = mix(1, coat_color,
coat)``. With ``coat_color`` white (MaterialX's default), ``coat_IOR`` 1.5 (its default,
a lacquer's) and ``coat_affect_color`` / ``coat_affect_roughness`` 0 (theirs):

    alpha_c = coat_roughness^2
    F_c     = exact dielectric Fresnel(cos_d; 1.5),  F0_c = 0.04
    comp_c  = 1 + F_c (1 - E_c) / E_c,   E_c = A_c + B_c at (cos_o, alpha_c)
    coat    = coat D_c V2_c F_c comp_c
    T_c     = 1 - coat comp_c (F0_c A_c + B_c)
    f       = coat + T_c f_standard_surface

with D, V2, E, A and B the GGX terms of ``standard_surface`` at the coat's alpha. The
coat sees the view alone in its throughput, as MaterialX's does: not reciprocal. At
``coat = 0`` it is ``standard_surface`` exactly: a fit starts from that fit with the
coat off (``parent``), beside starts that put a coat over each broad base of
``standard_surface``'s starts. ``tests/test_materialx_shading.py`` checks it against
MaterialX's generated GLSL.

| name               | range             | meaning (the MaterialX input)                  |
|--------------------|-------------------|------------------------------------------------|
| (standard_surface's five)                ||                                             |
| coat               | [0, 1]            | the coat's weight                              |
| coat_roughness     | [0.0316, 1] (log) | alpha = roughness^2                            |
"""

from __future__ import annotations

import math

from .base import Params, ParamSpec
from .frame import Frame
from .standard_surface import dielectric_lobe, ggx_lobe_terms, specular_alpha
from .standard_surface_layer import BASE, StandardSurfaceLayer

COAT = ParamSpec("coat", "coat: the clear coat's weight", 0.0, 1.0)
COAT_ROUGHNESS = ParamSpec("coat_roughness", "coat_roughness (alpha = roughness^2)",
                           math.sqrt(1e-3), 1.0, scale="log")
#: The coat's index: MaterialX's default ``coat_IOR``, a lacquer's (glTF's clear coat's
#: too); held, and written by the export.
COAT_IOR = 1.5
#: The coats a fit starts from over every broad base (beside the base's fit, coat off).
COAT_STARTS = tuple({"coat": 0.5, "coat_roughness": r} for r in (0.05, 0.15))


def coat_terms(coat, coat_roughness, frame: Frame):
    """MaterialX's coat (``mx_dielectric_bsdf`` at ``COAT_IOR``, white, reflection):
    its BRDF (...) and its throughput (...), what the layers under it are weighted by."""
    lobe, albedo = dielectric_lobe(COAT_IOR, ggx_lobe_terms(specular_alpha(coat_roughness),
                                                            frame))
    return coat * lobe, 1.0 - coat * albedo


class StandardSurfaceCoat(StandardSurfaceLayer):
    """``standard_surface`` with its coat (module docstring)."""

    layer_specs = (COAT, COAT_ROUGHNESS)
    layer_starts = COAT_STARTS

    @property
    def name(self) -> str:
        return "standard_surface_coat"

    @property
    def layer_params(self) -> dict[str, tuple[str, tuple[str, ...]]]:
        return {"clearcoat": ("coat", ("coat_roughness",))}

    def embed_parent(self, parent_params: dict) -> dict:
        """The ``standard_surface`` fit with the coat off, ready to grow."""
        return {**parent_params, "coat": 0.0, "coat_roughness": 0.1}

    def eval_channels(self, params: Params, frame: Frame):
        base = BASE.eval_channels(params, frame)
        coat, throughput = coat_terms(params["coat"], params["coat_roughness"], frame)
        return coat[None] + throughput[None] * base
