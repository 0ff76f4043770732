"""GGX / Trowbridge-Reitz microfacet lobe (Walter et al. 2007), height-correlated Smith.

D = alpha^2 / (pi (cos_h^2 (alpha^2 - 1) + 1)^2),
Lambda(w) = (-1 + sqrt(1 + alpha^2 tan^2 theta_w)) / 2.

| name  | range        | meaning                                   |
|-------|--------------|-------------------------------------------|
| kd    | [0, inf)     | diffuse albedo, RGB                       |
| ks    | [0, inf)     | specular scale, RGB                       |
| alpha | [1e-3, 2]    | roughness (log scale in the fit)          |
| f0    | [0, 1]       | Schlick reflectance at normal incidence   |
| eta   | [1, 3]       | index of refraction, instead of f0 with   |
|       |              | ``fresnel="dielectric"`` (microfacet.py)  |
"""

from __future__ import annotations

import jax.numpy as jnp

from .microfacet import AbstractMicrofacetModel


class GGX(AbstractMicrofacetModel):
    family = "ggx"
    #: with Schlick's Fresnel (the docs/models.md form; ``example_params``)
    schlick_example = {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.7, 0.6], "alpha": 0.15, "f0": 0.6}

    def ndf(self, alpha, cos_h, sin2_h):
        a2 = alpha * alpha
        # cos^2 (a^2 - 1) + 1 written as cos^2 a^2 + sin^2: no cancellation near the peak
        t = cos_h * cos_h * a2 + sin2_h
        return a2 / (jnp.pi * t * t)

    def cos_lambda(self, alpha, cos, sin2):
        # cos * Lambda = (sqrt(cos^2 + a^2 sin^2) - cos) / 2, rationalised so that a
        # small a^2 sin^2 does not cancel: a^2 sin^2 / (2 (sqrt(.) + cos)).
        a2s2 = alpha * alpha * sin2
        return a2s2 / (2.0 * (jnp.sqrt(cos * cos + a2s2) + cos) + 1e-300)
