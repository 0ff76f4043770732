"""Mitsuba 3's principled BSDF as a dielectric with sheen: ``principled``.

Mitsuba's ``principled`` plugin (Burley's Disney BRDF) with ``metallic``,
``spec_trans``, ``spec_tint``, ``clearcoat``, ``flatness`` and ``anisotropic`` at 0 (their
defaults), for a direct light (``Principled::eval``, ``principledhelpers.h``):

    alpha    = max(0.001, roughness^2)                     (calc_dist_params)
    eta      = 2 / (1 - sqrt(0.08 specular)) - 1            (its specular -> index)
    spec     = F_d(cos_d; eta) D G1(wi) G1(wo) / (4 cos_i cos_o)
               (GGX, separable Smith, the exact dielectric Fresnel)
    diffuse  = base_color / pi [(1 - Fi/2)(1 - Fo/2) + Rr (Fo + Fi + Fo Fi (Rr - 1))]
               Fi = (1 - cos_i)^5, Fo = (1 - cos_o)^5, Rr = 2 roughness cos_d^2
               (Burley's diffuse and its retro-reflection; no (1 - F))
    sheen    = sheen (1 - cos_d)^5 lerp(1, base_color / lum(base_color), sheen_tint)
    f        = spec + diffuse + sheen

``lum`` is Mitsuba's luminance of an RGB colour (0.212671 R + 0.715160 G + 0.072169 B).

``principled_clearcoat`` (``Principled(clearcoat=True)``) adds Mitsuba's clearcoat lobe,
Burley's second specular lobe, as ``Principled::eval`` writes it (a layer that adds
to the rest rather than mixing with it, as Disney's):

    clearcoat_term = 0.25 clearcoat Fcc(cos_d) Dcc(cos_h) G1(wi) G1(wo)
    Fcc  = 0.04 + (1 - 0.04) (1 - cos_d)^5                  (calc_schlick, its eta > 1)
    Dcc  = (a^2 - 1) / (pi log(a^2) (1 + (a^2 - 1) cos_h^2)),  a = lerp(0.1, 0.001, gloss)
    G1(w) = 2 / (1 + sqrt(1 + 0.25^2 tan^2 w))              (GTR1, separable Smith GGX 0.25)

There is no ``1 / (4 cos_i cos_o)`` in Mitsuba's term (Disney's has it inside its G);
the model is Mitsuba's, checked against its ``BSDF.eval``. At clearcoat 0 it is
``principled`` exactly: a fit starts from that fit with the coat off (``parent``).
A fabric's light at grazing angles is the sheen's, which Mitsuba's ``roughplastic`` has
not: pink-felt's roughplastic reached its diffuse bound at 1.54x the conductor blend's
error, its principled is 0.84x (log_rmse 0.0086 against 0.0103; measured 2026-11-28).
``tests/test_export_tools.py`` checks the model against Mitsuba's ``BSDF.eval`` (to 4e-6).

| name       | range             | meaning (Mitsuba's parameter)                      |
|------------|-------------------|----------------------------------------------------|
| base_color | [0, 1], RGB       | ``base_color``                                     |
| roughness  | [0.0316, 1] (log) | ``roughness`` (alpha = roughness^2, at least 0.001) |
| specular   | [0.001, 1]        | ``specular``: reflectance at normal incidence / 0.08 |
| sheen      | [0, 1]            | ``sheen``                                          |
| sheen_tint | [0, 1]            | ``sheen_tint``                                     |
| clearcoat  | [0, 1]            | ``clearcoat`` (``principled_clearcoat`` only)      |
| clearcoat_gloss | [0, 1]       | ``clearcoat_gloss``: GTR1 roughness 0.1 (0) .. 0.001 (1) |
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .base import AbstractBRDFModel, Params, ParamSpec
from .frame import Frame
from .guarded import safe_div, safe_sqrt
from .microfacet import ALPHA_GRID, dielectric_fresnel
from .renderer_terms import burley_diffuse, gtr1_d, schlick_weight, separable_ggx_dg

BASE_COLOR = ParamSpec("base_color", "base colour (diffuse and sheen tint), RGB", 0.0, 1.0,
                       rgb=True)
ROUGHNESS = ParamSpec("roughness", "roughness (alpha = roughness^2)", math.sqrt(1e-3), 1.0,
                      scale="log")
SPECULAR = ParamSpec("specular", "specular: reflectance at normal incidence / 0.08", 1e-3, 1.0)
SHEEN = ParamSpec("sheen", "weight of the sheen lobe", 0.0, 1.0)
SHEEN_TINT = ParamSpec("sheen_tint", "how much the sheen takes the base colour", 0.0, 1.0)
CLEARCOAT = ParamSpec("clearcoat", "weight of the clearcoat lobe", 0.0, 1.0)
CLEARCOAT_GLOSS = ParamSpec("clearcoat_gloss", "clearcoat_gloss: GTR1 roughness 0.1 .. 0.001",
                            0.0, 1.0)
#: The clear coat's gloss values a fit starts from (GTR1 roughness 0.07, 0.04, 0.01).
GLOSS_STARTS = (0.3, 0.6, 0.9)
#: Mitsuba's fixed roughness of the clearcoat's shadowing-masking.
CLEARCOAT_G_ALPHA = 0.25
#: Mitsuba's luminance weights of linear sRGB (``mitsuba::luminance``).
LUMINANCE = (0.212671, 0.715160, 0.072169)


def specular_eta(specular):
    """Mitsuba's index of refraction of a principled ``specular``."""
    return 2.0 / (1.0 - jnp.sqrt(0.08 * specular)) - 1.0


class Principled(AbstractBRDFModel):
    #: True: ``principled_clearcoat``, Mitsuba's clearcoat lobe over the rest.
    clearcoat: bool = eqx.field(static=True, default=False)

    @property
    def name(self) -> str:
        return "principled_clearcoat" if self.clearcoat else "principled"

    @property
    def layer_params(self) -> dict[str, tuple[str, tuple[str, ...]]]:
        sheen = {"sheen": ("sheen", ("sheen_tint",))}  # Burley's sheen: a lobe of its own
        return {**sheen, "clearcoat": ("clearcoat", ("clearcoat_gloss",))} if self.clearcoat \
            else sheen

    @property
    def param_specs(self) -> tuple[ParamSpec, ...]:
        coat = (CLEARCOAT, CLEARCOAT_GLOSS) if self.clearcoat else ()
        return (BASE_COLOR, ROUGHNESS, SPECULAR, SHEEN, SHEEN_TINT, *coat)

    @property
    def shape_grid(self) -> tuple[dict[str, float], ...]:
        base = tuple({"roughness": min(math.sqrt(a), 1.0), "specular": 0.5, "sheen": s,
                      "sheen_tint": 0.5} for a in ALPHA_GRID for s in (0.0, 0.5))
        if not self.clearcoat:
            return base
        # a coat over a base broader than it
        return tuple({**shape, "clearcoat": 0.5, "clearcoat_gloss": g}
                     for shape in base if shape["roughness"] >= 0.2 for g in GLOSS_STARTS)

    @property
    def parent(self) -> str | None:
        return "principled" if self.clearcoat else None

    def embed_parent(self, parent_params: dict) -> dict:
        if not self.clearcoat:
            return super().embed_parent(parent_params)
        return {**parent_params, "clearcoat": 0.0, "clearcoat_gloss": 0.6}

    def eval_channels(self, params: Params, frame: Frame):
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        base, r = params["base_color"][expand], params["roughness"]
        alpha = jnp.maximum(1e-3, r * r)
        spec = dielectric_fresnel(specular_eta(params["specular"]), frame.cos_d) * separable_ggx_dg(
            alpha, frame.cos_h, frame.sin2_h, frame.cos_i, frame.sin2_i, frame.cos_o,
            frame.sin2_o)
        burley = burley_diffuse(r, frame.cos_i, frame.cos_o, frame.cos_d)
        lum = sum(w * params["base_color"][c] for c, w in enumerate(LUMINANCE))
        tint = jnp.where(lum > 0.0, params["base_color"] / jnp.where(lum > 0.0, lum, 1.0), 1.0)
        c_sheen = (1.0 + params["sheen_tint"] * (tint - 1.0))[expand]
        sheen = params["sheen"] * schlick_weight(frame.cos_d)
        f = spec[None] + base / jnp.pi * burley[None] + sheen[None] * c_sheen
        if not self.clearcoat:
            return f
        return f + _clearcoat_term(params["clearcoat"], params["clearcoat_gloss"], frame)[None]

    def eval_frame(self, params: Params, frame: Frame):
        return jnp.moveaxis(self.eval_channels(params, frame), 0, -1)

    def start_candidates(self, table, usable: np.ndarray, kd: np.ndarray) -> np.ndarray:
        """Unconstrained starts, one per (roughness, sheen[, clearcoat gloss]) on
        ``shape_grid``, the base colour the diffuse estimate."""
        base = np.clip(kd, 0.02, 0.98)
        return np.stack([self.unconstrain({**shape, "base_color": base})
                         for shape in self.shape_grid])


def _clearcoat_term(clearcoat, gloss, frame: Frame):
    """Mitsuba's clearcoat lobe (module docstring), f_r (1/sr), shared by R, G, B."""
    a = 0.1 + (0.001 - 0.1) * gloss  # dr::lerp(0.1, 0.001, gloss)
    d = gtr1_d(a, frame.cos_h)
    fresnel = 0.04 + (1.0 - 0.04) * schlick_weight(frame.cos_d)
    return 0.25 * clearcoat * fresnel * d * _smith_g1(frame.cos_i, frame.sin2_i) * _smith_g1(
        frame.cos_o, frame.sin2_o)


def _smith_g1(cos, sin2):
    """Mitsuba's ``smith_ggx1`` at roughness 0.25: ``2 / (1 + sqrt(1 + a^2 tan^2))``, as
    ``2 cos / (cos + sqrt(cos^2 + a^2 sin^2))``: no cosine in a denominator, 0 at grazing."""
    a2 = CLEARCOAT_G_ALPHA * CLEARCOAT_G_ALPHA
    return safe_div(2.0 * cos, cos + safe_sqrt(cos * cos + a2 * sin2), 1e-30)
