"""Shared microfacet maths (Walter et al. 2007; Heitz 2014), used by GGX and Beckmann.

lobe = F * D * G / (4 cos_i cos_o), with height-correlated Smith
G = 1 / (1 + Lambda(wi) + Lambda(wo)) and Schlick F = f0 + (1 - f0)(1 - cos_d)^5.

Why ``cos_lambda``: each distribution supplies ``cos * Lambda(cos)`` instead of
Lambda. Then

    G / (4 cos_i cos_o) = 1 / (4 (cos_i cos_o + cos_o (cos_i Lambda_i) + cos_i (cos_o Lambda_o)))

which is finite at grazing angles (Lambda -> inf while cos * Lambda stays bounded)
and needs no tan(theta). Only both directions exactly grazing floor the
denominator.
"""

from __future__ import annotations

import abc

import jax.numpy as jnp
from jaxtyping import Array, Float

from .base import KD, KS, AbstractLobeModel, ParamSpec
from .frame import Frame
from .guarded import safe_div

ALPHA = ParamSpec("alpha", "roughness (slope scale)", 1e-3, 2.0, scale="log")
F0 = ParamSpec("f0", "Fresnel reflectance at normal incidence", 0.0, 1.0)

ALPHA_GRID = (0.002, 0.005, 0.01, 0.02, 0.04, 0.08, 0.15, 0.3, 0.5, 0.8)


def schlick_fresnel(f0, cos_d: Float[Array, "..."]) -> Float[Array, "..."]:
    return f0 + (1.0 - f0) * (1.0 - cos_d) ** 5


class AbstractMicrofacetModel(AbstractLobeModel):
    """A microfacet lobe; subclasses give the normal distribution and its Lambda."""

    param_specs = (KD, KS, ALPHA, F0)
    shape_grid = tuple({"alpha": a, "f0": f} for a in ALPHA_GRID for f in (0.3, 1.0))

    @abc.abstractmethod
    def ndf(self, alpha, cos_h, sin2_h) -> Float[Array, "..."]:
        """D(h) in 1/sr (projected-area normalised)."""

    @abc.abstractmethod
    def cos_lambda(self, alpha, cos, sin2) -> Float[Array, "..."]:
        """cos(theta) * Lambda(theta): Smith's Lambda times the cosine, bounded."""

    def fresnel(self, params, cos_d):
        return schlick_fresnel(params["f0"], cos_d)

    def lobe(self, params, frame: Frame):
        alpha = params["alpha"]
        ci, co = frame.cos_i, frame.cos_o
        den = 4.0 * (
            ci * co
            + co * self.cos_lambda(alpha, ci, frame.sin2_i)
            + ci * self.cos_lambda(alpha, co, frame.sin2_o)
        )
        d = self.ndf(alpha, frame.cos_h, frame.sin2_h)
        return self.fresnel(params, frame.cos_d) * safe_div(d, den, 1e-30)
