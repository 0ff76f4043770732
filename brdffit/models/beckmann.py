"""Beckmann microfacet lobe, height-correlated Smith.

D = exp(-tan^2(theta_h) / alpha^2) / (pi alpha^2 cos_h^4),
Lambda(w) = (erf(m) - 1)/2 + exp(-m^2) / (2 m sqrt(pi)),  m = 1 / (alpha tan theta_w).

| name  | range        | meaning                                   |
|-------|--------------|-------------------------------------------|
| kd    | [0, inf)     | diffuse albedo, RGB                       |
| ks    | [0, inf)     | specular scale, RGB                       |
| alpha | [1e-3, 2]    | RMS slope (log scale in the fit)          |
| f0    | [0, 1]       | Schlick reflectance at normal incidence   |
| eta   | [1, 3]       | index of refraction, instead of f0 with   |
|       |              | ``fresnel="dielectric"`` (microfacet.py)  |
"""

from __future__ import annotations

import math

import jax.numpy as jnp
from jax.scipy.special import erfc

from .guarded import safe_div, safe_sqrt
from .microfacet import AbstractMicrofacetModel

_SQRT_PI = math.sqrt(math.pi)


class Beckmann(AbstractMicrofacetModel):
    family = "beckmann"
    #: with Schlick's Fresnel (the docs/models.md form; ``example_params``)
    schlick_example = {"kd": [0.15, 0.1, 0.3], "ks": [0.5, 0.6, 0.7], "alpha": 0.25, "f0": 0.4}

    def ndf(self, alpha, cos_h, sin2_h):
        a2 = alpha * alpha
        c2 = cos_h * cos_h
        tan2 = safe_div(sin2_h, c2, 1e-300)
        # exp(-tan^2/a^2) / cos^4 in log space: both factors blow up at grazing h.
        # tan^2/a^2 capped at 1e4, where exp(-it) is 0 whatever the other terms (they
        # add at most ~1400): uncapped, a grazing h at alpha 1e-3 has a slope in alpha
        # of inf, which forward mode multiplies by exp'(...) = 0 into a NaN. The cap is
        # on tan^2 (a min's slope is its operand's times a mask: it must be finite)
        log_d = (-jnp.minimum(tan2, 1e4 * a2) / a2 - 2.0 * jnp.log(jnp.maximum(c2, 1e-300))
                 - jnp.log(jnp.pi * a2))
        return jnp.exp(jnp.minimum(log_d, 700.0))

    def cos_lambda(self, alpha, cos, sin2):
        # cos * Lambda = -cos erfc(m)/2 + (cos/m) exp(-m^2)/(2 sqrt(pi)), with
        # cos/m = alpha sin: bounded at grazing (m -> 0) and at the normal (m -> inf).
        a_sin = alpha * safe_sqrt(sin2)
        # the floor squared must stay a normal number (the quotient rule squares it,
        # and 1e-300 squared is 0: a NaN slope at the normal); m is capped at 1e4 anyway
        m = jnp.minimum(safe_div(cos, a_sin, 1e-12), 1e4)
        return -cos * erfc(m) / 2.0 + a_sin * jnp.exp(-m * m) / (2.0 * _SQRT_PI)
