"""MaterialX standard_surface with its sheen, as its GLSL shades it:
``standard_surface_sheen``.

The ``standard_surface`` node (``standard_surface``, this package) with the sheen of its
nodegraph (``NG_standard_surface_surfaceshader_100``): a ``sheen_bsdf`` (mode
``conty_kulla``, MaterialX's default) of weight ``sheen``, colour ``sheen_color`` and
roughness ``sheen_roughness``, layered over the diffuse alone (``sheen_layer``, under the
specular layer and beside the metal), as MaterialX 1.39's GLSL evaluates it
(``mx_sheen_bsdf``, ``mx_imageworks_sheen_brdf``,
``mx_imageworks_sheen_dir_albedo_analytic``):

    D       = (2 + 1/r) s^(1/(2r)) / (2 pi),   r = max(sheen_roughness, 0.005),
              s = 1 - cos_h^2                                 (Conty and Kulla's Charlie)
    sheen   = sheen sheen_color D / (4 (cos_i + cos_o - cos_i cos_o))
    T_s     = 1 - sheen E_s(cos_o, sheen_roughness)    (E_s: MaterialX's rational fit of
                                                        the sheen's directional albedo)
    f       = m metal + (1 - m) (spec + T (sheen + T_s diffuse))

with ``metal``, ``spec``, ``T`` and ``diffuse`` ``standard_surface``'s (cosines clamped
to 1e-8 as MaterialX's). ``sheen`` (the weight) and ``sheen_color`` multiply each other
in the lobe; the weight alone dims the diffuse, so both are fitted: at ``sheen = 0`` it
is ``standard_surface`` exactly, its ``parent``, from whose fit (the sheen off) a fit
starts, beside a white sheen of weight 0.5 at roughness 0.3 and 0.6 over every broad
base. ``tests/test_materialx_shading.py`` checks it against MaterialX's generated GLSL.

| name            | range             | meaning (the MaterialX input)                   |
|-----------------|-------------------|-------------------------------------------------|
| (standard_surface's five)             ||                                               |
| sheen           | [0, 1]            | the sheen's weight                              |
| sheen_color     | [0, 1], RGB       | the sheen's colour                              |
| sheen_roughness | [0.01, 1] (log)   | the fibres' spread: D's power is 1/(2 r)        |
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .base import Params, ParamSpec
from .frame import Frame
from .standard_surface_layer import BASE, StandardSurfaceLayer

SHEEN = ParamSpec("sheen", "sheen: the sheen's weight", 0.0, 1.0)
SHEEN_COLOR = ParamSpec("sheen_color", "sheen_color: the sheen's colour", 0.0, 1.0, rgb=True)
#: The sheen's least roughness, 0.01: D's power 50, the sharpest grazing lobe of
#: gltf_sheen's least roughness (its alpha 0.01 takes the same power).
SHEEN_ROUGHNESS = ParamSpec("sheen_roughness", "sheen_roughness: the fibres' spread",
                            0.01, 1.0, scale="log")
#: MaterialX's floor of the roughness in D (``mx_imageworks_sheen_NDF``).
NDF_MIN_ROUGHNESS = 0.005
#: The sheens a fit starts from over every broad base (beside the base's fit, sheen off).
SHEEN_STARTS = tuple({"sheen": 0.5, "sheen_color": 1.0, "sheen_roughness": r}
                     for r in (0.3, 0.6))
#: ``mx_imageworks_sheen_dir_albedo_analytic``: numerator and denominator coefficients of
#: 1, x, y, x y, x^2, y^2 (x = cos_o, y = roughness).
_ALBEDO_FIT = np.array([[13.67300, -68.78018, 799.08825, -905.00061, 60.28956, 1086.96473],
                        [1.0, 61.57746, 442.78211, 2597.49308, 121.81241, 3045.55075]])


def sheen_dir_albedo(cos_o, roughness):
    """MaterialX's rational fit of the Charlie sheen's directional albedo, clamped to
    [0, 1] as ``mx_imageworks_sheen_dir_albedo`` clamps it (the fit passes 1 at grazing
    views of sharp sheens: 1.3 at cos_o 0.06, roughness 0.05)."""
    x, y = cos_o, roughness
    terms = (1.0, x, y, x * y, x * x, y * y)
    num, den = (sum(c * t for c, t in zip(row, terms, strict=True)) for row in _ALBEDO_FIT)
    return jnp.clip(num / den, 0.0, 1.0)  # den >= 1 on [0, 1]^2: positive coefficients


def sheen_terms(params: Params, frame: Frame):
    """MaterialX's sheen: its BRDF (3, ...) and its throughput (...)."""
    expand = (slice(None),) + (None,) * frame.cos_i.ndim
    ci = jnp.maximum(frame.cos_i, 1e-8)
    co = jnp.maximum(frame.cos_o, 1e-8)
    ch = jnp.clip(frame.cos_h, 1e-8, 1.0)
    inv_r = 1.0 / jnp.maximum(params["sheen_roughness"], NDF_MIN_ROUGHNESS)
    sin2 = 1.0 - ch * ch
    # sin2 ** (inv_r / 2), 0 at the normal (sin2 = 0) as the GLSL's pow, with a finite
    # gradient there
    power = jnp.where(sin2 > 0.0, jnp.exp(jnp.log(jnp.where(sin2 > 0.0, sin2, 1.0))
                                          * (0.5 * inv_r)), 0.0)
    d = (2.0 + inv_r) * power / (2.0 * jnp.pi)
    lobe = d / (4.0 * (ci + co - ci * co))
    weight = params["sheen"]
    brdf = weight * params["sheen_color"][expand] * lobe[None]
    throughput = 1.0 - sheen_dir_albedo(co, params["sheen_roughness"]) * weight
    return brdf, throughput


class StandardSurfaceSheen(StandardSurfaceLayer):
    """``standard_surface`` with its sheen (module docstring)."""

    layer_specs = (SHEEN, SHEEN_COLOR, SHEEN_ROUGHNESS)
    layer_starts = SHEEN_STARTS

    @property
    def name(self) -> str:
        return "standard_surface_sheen"

    @property
    def layer_params(self) -> dict[str, tuple[str, tuple[str, ...]]]:
        return {"sheen": ("sheen", ("sheen_color", "sheen_roughness"))}

    def embed_parent(self, parent_params: dict) -> dict:
        """The ``standard_surface`` fit with the sheen off, ready to grow."""
        return {**parent_params, "sheen": 0.0, "sheen_color": np.ones(3),
                "sheen_roughness": 0.3}

    def eval_channels(self, params: Params, frame: Frame):
        m, metal, spec, throughput, diffuse = BASE.shading_terms(params, frame)
        sheen, sheen_throughput = sheen_terms(params, frame)
        under = sheen + sheen_throughput[None] * diffuse
        return m * metal + (1.0 - m) * (spec + throughput[None] * under)
