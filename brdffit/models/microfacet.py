"""Shared microfacet maths (Walter et al. 2007; Heitz 2014), used by GGX, Beckmann and GGX2.

lobe = F * D * G / (4 cos_i cos_o), with height-correlated Smith
G = 1 / (1 + Lambda(wi) + Lambda(wo)) and a Fresnel term F, one of:

- ``"schlick"`` (default, docs/models.md): F = f0 + (1 - f0)(1 - cos_d)^5, parameter ``f0``;
- ``"dielectric"``: the exact unpolarised Fresnel reflectance of a dielectric of
  relative index ``eta`` (Walter et al. 2007, eq. 22), parameter ``eta`` instead
  of ``f0``:

      g = sqrt(eta^2 - 1 + c^2),  c = cos_d
      F = 1/2 (g - c)^2 / (g + c)^2 * (1 + ((c (g + c) - 1) / (c (g - c) + 1))^2)

  F(normal) = ((eta - 1)/(eta + 1))^2 and F -> 1 at grazing, with the dip and rise
  a real dielectric has, where Schlick's polynomial only approximates it.

Why ``cos_lambda``: each distribution supplies ``cos * Lambda(cos)`` instead of
Lambda. Then

    G / (4 cos_i cos_o) = 1 / (4 (cos_i cos_o + cos_o (cos_i Lambda_i) + cos_i (cos_o Lambda_o)))

which is finite at grazing angles (Lambda -> inf while cos * Lambda stays bounded)
and needs no tan(theta). Only both directions exactly grazing floor the
denominator.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
from jaxtyping import Array, Float

from .base import KD, KS, AbstractLobeModel, Params, ParamSpec
from .frame import Frame
from .guarded import safe_div, safe_sqrt

ALPHA = ParamSpec("alpha", "roughness (slope scale)", 1e-3, 2.0, scale="log")
F0 = ParamSpec("f0", "Fresnel reflectance at normal incidence", 0.0, 1.0)
ETA = ParamSpec("eta", "relative index of refraction (dielectric Fresnel)", 1.0, 3.0)

ALPHA_GRID = (0.002, 0.005, 0.01, 0.02, 0.04, 0.08, 0.15, 0.3, 0.5, 0.8)

#: Fresnel options: name -> (its parameter, the values a fit starts from).
FRESNELS: dict[str, tuple[ParamSpec, tuple[float, ...]]] = {
    # not 1.0: a start on the sigmoid's flat tail (u ~ 14) costs the solver ~10 steps
    "schlick": (F0, (0.25, 0.9)),
    # water, glass, a high-index coating: F(normal) = 0.02, 0.04, 0.14
    "dielectric": (ETA, (1.33, 1.5, 2.2)),
}


def schlick_fresnel(f0, cos_d: Float[Array, ...]) -> Float[Array, ...]:
    return f0 + (1.0 - f0) * (1.0 - cos_d) ** 5


def dielectric_fresnel(eta, cos_d: Array) -> Array:
    """Exact unpolarised Fresnel reflectance, eta >= 1 (Walter et al. 2007, eq. 22)."""
    c = cos_d
    # g >= c >= 0 for eta >= 1, so c (g - c) + 1 >= 1; g + c is 0 only at eta = 1
    # and grazing, where the ratio's limit is 0 (the floor returns exactly that).
    g = safe_sqrt(eta * eta - 1.0 + c * c)
    r = safe_div(g - c, g + c, 1e-30)
    s = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    return 0.5 * r * r * (1.0 + s * s)


def fresnel_term(kind: str, params: Params, cos_d: Array) -> Array:
    """The Fresnel factor of option ``kind`` (see ``FRESNELS``) from ``params``."""
    if kind == "dielectric":
        return dielectric_fresnel(params["eta"], cos_d)
    return schlick_fresnel(params["f0"], cos_d)


def check_fresnel(kind: str) -> None:
    if kind not in FRESNELS:
        raise ValueError(f"unknown fresnel {kind!r}; choose one of {', '.join(FRESNELS)}")


class AbstractMicrofacetModel(AbstractLobeModel):
    """A microfacet lobe; subclasses give the normal distribution and its Lambda.

    ``fresnel`` picks the Fresnel term (``"schlick"``: parameter ``f0``, the
    docs/models.md model; ``"dielectric"``: parameter ``eta``). The model's name is the
    distribution's (``"ggx"``) or, for a non-default Fresnel, ``"ggx_dielectric"``.
    """

    fresnel: str = eqx.field(static=True, default="schlick")
    #: The distribution's name; ``name`` adds the Fresnel option.
    family: ClassVar[str]

    def __check_init__(self):
        check_fresnel(self.fresnel)

    @property
    def name(self) -> str:
        return self.family if self.fresnel == "schlick" else f"{self.family}_{self.fresnel}"

    #: ``example_params`` of the Schlick form; the other Fresnel forms give none.
    schlick_example: ClassVar[dict | None] = None

    @property
    def example_params(self) -> dict | None:
        return self.schlick_example if self.fresnel == "schlick" else None

    @property
    def auto_candidate(self) -> bool:
        """The docs/models.md form (Schlick's Fresnel) is one of auto's candidates."""
        return self.fresnel == "schlick"

    @property
    def param_specs(self) -> tuple[ParamSpec, ...]:
        return (KD, KS, ALPHA, FRESNELS[self.fresnel][0])

    @property
    def shape_grid(self) -> tuple[dict[str, float], ...]:
        spec, values = FRESNELS[self.fresnel]
        return tuple({"alpha": a, spec.name: v} for a in ALPHA_GRID for v in values)

    @abc.abstractmethod
    def ndf(self, alpha, cos_h, sin2_h) -> Float[Array, ...]:
        """D(h) in 1/sr (projected-area normalised)."""

    @abc.abstractmethod
    def cos_lambda(self, alpha, cos, sin2) -> Float[Array, ...]:
        """cos(theta) * Lambda(theta): Smith's Lambda times the cosine, bounded."""

    def shadowed_ndf(self, alpha, frame: Frame) -> Array:
        """D G / (4 cos_i cos_o): the lobe without its Fresnel factor."""
        ci, co = frame.cos_i, frame.cos_o
        den = 4.0 * (
            ci * co
            + co * self.cos_lambda(alpha, ci, frame.sin2_i)
            + ci * self.cos_lambda(alpha, co, frame.sin2_o)
        )
        d = self.ndf(alpha, frame.cos_h, frame.sin2_h)
        return safe_div(d, den, 1e-30)

    def lobe(self, params, frame: Frame):
        return fresnel_term(self.fresnel, params, frame.cos_d) * self.shadowed_ndf(
            params["alpha"], frame
        )
