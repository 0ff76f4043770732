"""MaterialX standard_surface as its GLSL shades it: dielectric over Oren-Nayar, and a metal.

The BRDF of the ``standard_surface`` node (``libraries/bxdf/standard_surface.mtlx``,
nodegraph ``NG_standard_surface_surfaceshader_100``) for a direct light, with coat,
sheen, subsurface, transmission, thin film and emission off and ``specular_anisotropy``
0, evaluated the way MaterialX 1.39.5's GLSL generator evaluates it (``pbrlib/genglsl``,
default options: analytic directional albedo). ``wi`` is the light L, ``wo`` the view V;
the generated light loop adds ``intensity * response`` and every BSDF's ``response`` is
f_r cos_i, so f_r = response / cos_i (divided out in closed form below):

    alpha   = specular_roughness^2                        (mx_roughness_anisotropy)
    D       = alpha^2 / (pi (sin_h^2 + alpha^2 cos_h^2)^2)            (mx_ggx_NDF)
    V2      = 1 / (2 (lam_i cos_o + lam_o cos_i)),  lam = sqrt(cos^2 + alpha^2 sin^2)
              (= G2 / (4 cos_i cos_o), mx_ggx_smith_G2, height-correlated)
    E(c)    = the analytic GGX directional albedo for F0 = F90 = 1 at cos_o = c
              (mx_ggx_dir_albedo_analytic: a rational fit, A + B)
    comp(F) = 1 + F (1 - E) / E                          (mx_ggx_energy_compensation)
    F_d     = exact dielectric Fresnel(cos_d; specular_IOR)     (mx_fresnel_dielectric)
    spec    = specular_color D V2 F_d comp(F_d)                      (mx_dielectric_bsdf)
    T       = 1 - comp(F_d) (F0 A + B),  F0 = ((ior-1)/(ior+1))^2       (its throughput)
    diff    = base_color / pi            (mx_oren_nayar_diffuse at diffuse_roughness 0)
    n, k    = artistic_ior(base_color, specular_color)                 (mx_artistic_ior)
    metal   = D V2 F_c(cos_d; n, k) comp(F_c)   (mx_conductor_bsdf, mx_fresnel_conductor)
    f       = metalness metal + (1 - metalness) (spec + T diff)       (mix, layer)

``base`` and ``base_color`` enter only as their product (the diffuse colour and the
metal's reflectivity), so ``base`` is not fitted: it is 1. ``specular`` (the dielectric's
weight) is MaterialX's default 1, not fitted: it multiplies ``specular_color`` everywhere
but in the throughput T, and where the diffuse is black the two are one parameter (a fit
then ran to its step limit: nickel, gold-metallic-paint); fitted, it gained 2-4% log_rmse
on red-plastic and pink-fabric (measured 2026-11-26). ``diffuse_roughness`` (MaterialX's
Oren-Nayar sigma) is its default 0, Lambert: fitted, it gained nothing on nickel, brass,
chrome, blue-fabric and pink-felt and 0.2% on red-plastic and pink-fabric (2026-11-26).
The other parameters are MaterialX's inputs under their names.

| name               | range             | meaning (the MaterialX input)                  |
|--------------------|-------------------|------------------------------------------------|
| base_color         | [0, 1], RGB       | diffuse colour; the metal's reflectivity       |
| metalness          | [0, 1]            | mix weight of the conductor                    |
| specular_color     | [0, 1], RGB       | tint of the dielectric; the metal's edge colour |
| specular_roughness | [0.0316, 1] (log) | alpha = roughness^2; lower bound alpha = 1e-3  |
| specular_IOR       | [1, 50] (log)     | the dielectric's index of refraction           |

Not reciprocal: E, comp and T read the view's cosine (as MaterialX's do). Cosines are
clamped to 1e-8 as MaterialX clamps them (``M_FLOAT_EPS``). T can dip below 0 (to
-0.007 at cos_o = 1e-8, alpha 1e-3, index 50; E's fit reaches 1.03), as MaterialX's does.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .base import AbstractBRDFModel, Params, ParamSpec
from .computed_once import computed_once
from .frame import Frame, shading_frame
from .guarded import safe_div, safe_sqrt
from .microfacet import ALPHA_GRID, dielectric_fresnel
from .renderer_terms import conductor_fresnel

BASE_COLOR = ParamSpec("base_color", "base_color: diffuse colour and metal reflectivity (RGB)",
                       0.0, 1.0, rgb=True)
METALNESS = ParamSpec("metalness", "metalness: mix weight of the conductor", 0.0, 1.0)
SPECULAR_COLOR = ParamSpec("specular_color", "specular_color: specular tint, metal edge colour",
                           0.0, 1.0, rgb=True)
SPECULAR_ROUGHNESS = ParamSpec("specular_roughness", "specular_roughness (alpha = roughness^2)",
                               math.sqrt(1e-3), 1.0, scale="log")
#: MaterialX's soft range is [1, 3] (no hard bound above): a measured metal fits best as
#: a tinted dielectric of a large index, whose Fresnel curve is flat (F0 0.8 at 18;
#: nickel and gold-metallic-paint fitted 17.8-20 with this bound; upper bounds 10 and 3,
#: where those fits stopped, cost them 3-8% and 60-85% of their log_rmse, 2026-11-26).
SPECULAR_IOR = ParamSpec("specular_IOR", "specular_IOR: index of refraction of the dielectric",
                         1.0, 50.0, scale="log")
#: standard_surface_dielectric's index: at most a dense glass's or a gem's. An index of
#: 15 has a metal's reflectance (f0 0.77): a "dielectric" that is a metal in all but
#: name, which is what the class check (brdffit.export.conversion) must not export.
DIELECTRIC_IOR = ParamSpec("specular_IOR", "specular_IOR: index of refraction of the dielectric",
                           1.0, 3.0)

#: The ``standard_surface`` inputs the model holds at a value instead of fitting them
#: (MaterialX's defaults; the export writes them); every other input not fitted is off.
FIXED_INPUTS = {"base": 1.0, "specular": 1.0, "diffuse_roughness": 0.0}

# mx_ggx_dir_albedo_analytic's rational fit: rows (A numerator, B numerator, A
# denominator, B denominator), columns the coefficients of 1, x, y, x y, x^2, y^2,
# x^2 y, x y^2, x^2 y^2 with x = cos_o, y = alpha.
_ALBEDO_FIT = np.array([
    [0.1003, -0.6303, 9.748, -2.038, 29.34, -8.245, -26.44, 19.99, -5.448],
    [0.9345, -2.323, 2.229, -3.748, 1.424, -0.7684, 1.436, 0.2913, 0.6286],
    [1.0, -1.765, 8.263, 11.53, 28.96, -7.507, -36.11, 15.86, 33.37],
    [1.0, 0.2281, 15.94, -55.83, 13.08, 41.26, 54.9, 300.2, -285.1],
])


def ggx_dir_albedo_ab(cos_o, alpha):
    """(A, B) of MaterialX's ``mx_ggx_dir_albedo_analytic``: the GGX directional albedo
    is ``F0 A + F90 B`` (each clamped to [0, 1] as there)."""
    x, y = cos_o, alpha
    terms = (1.0, x, y, x * y, x * x, y * y, x * x * y, x * y * y, x * x * y * y)
    r = [sum(c * t for c, t in zip(row, terms, strict=True)) for row in _ALBEDO_FIT]
    # the denominators stay >= 0.97 on [0, 1]^2 (checked on a 1001^2 grid): the floor
    # only guards the gradient
    a = jnp.clip(safe_div(r[0], r[2], 1e-6), 0.0, 1.0)
    b = jnp.clip(safe_div(r[1], r[3], 1e-6), 0.0, 1.0)
    return a, b


def artistic_ior(reflectivity, edge_color):
    """MaterialX's ``mx_artistic_ior`` (Gulbrandsen 2014): conductor (n, k) whose Fresnel
    has ``reflectivity`` at normal incidence and bends towards ``edge_color``."""
    r = jnp.clip(reflectivity, 0.0, 0.99)
    r_sqrt = safe_sqrt(r)
    n_min = (1.0 - r) / (1.0 + r)
    n_max = (1.0 + r_sqrt) / (1.0 - r_sqrt)
    n = n_max * (1.0 - edge_color) + n_min * edge_color
    k2 = ((n + 1.0) ** 2 * r - (n - 1.0) ** 2) / (1.0 - r)
    return n, safe_sqrt(k2)


def specular_alpha(roughness):
    """GGX alpha of ``specular_roughness``: MaterialX's ``mx_roughness_anisotropy``
    (anisotropy 0) and the BSDFs' ``clamp(alpha, 1e-8, 1)``."""
    return jnp.clip(roughness * roughness, 1e-8, 1.0)


def ggx_dv(alpha, frame: Frame):
    """``D G2 / (4 cos_i cos_o)``: MaterialX's ``mx_ggx_NDF`` and height-correlated
    ``mx_ggx_smith_G2`` (cosines clamped to 1e-8 as there), written
    ``D / (2 (lam_i cos_o + lam_o cos_i))``, ``lam = sqrt(cos^2 + alpha^2 sin^2)``: no
    cosine in a denominator."""
    ci = jnp.maximum(frame.cos_i, 1e-8)
    co = jnp.maximum(frame.cos_o, 1e-8)
    a2 = alpha * alpha
    t = frame.cos_h * frame.cos_h * a2 + frame.sin2_h  # (sin_h^2/a^2 + cos_h^2) a^2
    d = safe_div(a2, jnp.pi * t * t, 1e-30)
    lam_i = safe_sqrt(ci * ci + a2 * frame.sin2_i)
    lam_o = safe_sqrt(co * co + a2 * frame.sin2_o)
    return safe_div(d, 2.0 * (lam_i * co + lam_o * ci), 1e-30)


class LobeTerms(NamedTuple):
    """What MaterialX's dielectric and conductor lobes at one alpha share
    (:func:`ggx_lobe_terms`)."""

    dv: jnp.ndarray  # D G2 / (4 cos_i cos_o), :func:`ggx_dv`
    big_a: jnp.ndarray  # the albedo fit's A and B at the view
    big_b: jnp.ndarray
    ms_gain: jnp.ndarray  # (1 - E) / E: the energy compensation is 1 + F ms_gain
    cos_d: jnp.ndarray  # V.H, clamped to [1e-8, 1] as MaterialX clamps it


def ggx_lobe_terms(alpha, frame: Frame) -> LobeTerms:
    """:class:`LobeTerms` at ``alpha`` (cosines clamped to 1e-8, as MaterialX's).

    Computed once and stored (``computed_once``): the lobe and the albedo fit are read
    by the dielectric, the conductor and a layer's throughput, and XLA computed them
    again in each, per parameter's pass of a fit's Jacobian (standard_surface's
    normal equations on 16,384 samples: 11.3 -> 7.2 ms; its coat's 21.1 -> 12.7)."""

    def terms(operands):
        alpha, frame = operands
        co = jnp.maximum(frame.cos_o, 1e-8)
        big_a, big_b = ggx_dir_albedo_ab(co, alpha)
        e_ss = big_a + big_b
        return LobeTerms(ggx_dv(alpha, frame), big_a, big_b,
                         safe_div(1.0 - e_ss, e_ss, 1e-6), jnp.maximum(frame.cos_d, 1e-8))

    return computed_once(terms, (alpha, frame), frame.cos_o)


def dielectric_lobe(ior, terms: LobeTerms):
    """``mx_dielectric_bsdf``'s reflection, white and at weight 1: its lobe ``D V2 F_d
    comp(F_d)`` (...) and its directional albedo ``comp(F_d) (F0 A + B)`` (...), of
    which a layer under it sees ``1 - weight albedo`` (the BSDF's throughput)."""
    dv, big_a, big_b, ms_gain, cd = terms
    f_d = dielectric_fresnel(ior, cd)
    comp = 1.0 + f_d * ms_gain
    f0 = ((ior - 1.0) / (ior + 1.0)) ** 2
    return dv * f_d * comp, comp * (f0 * big_a + big_b)


class StandardSurface(AbstractBRDFModel):
    #: True: ``standard_surface_dielectric``, metalness held at 0 (not a parameter): the
    #: MaterialX export's dielectric alternative to a metal mixture
    #: (brdffit.export.conversion.dielectric_or_mixture).
    dielectric: bool = eqx.field(static=True, default=False)

    @property
    def name(self) -> str:
        return "standard_surface_dielectric" if self.dielectric else "standard_surface"

    @property
    def param_specs(self) -> tuple[ParamSpec, ...]:
        if self.dielectric:
            return (BASE_COLOR, SPECULAR_COLOR, SPECULAR_ROUGHNESS, DIELECTRIC_IOR)
        return (BASE_COLOR, METALNESS, SPECULAR_COLOR, SPECULAR_ROUGHNESS, SPECULAR_IOR)

    @property
    def start_family(self) -> str | None:
        # the best-scored start alone ended in a metal's basin on a dark dielectric and
        # in a dielectric's on a near-mirror metal (tests/quality_truths.py)
        return None if self.dielectric else "metalness"

    @property
    def shape_grid(self) -> tuple[dict[str, float], ...]:
        rows = ((0.0, 1.5), (0.0, 2.5)) if self.dielectric else (
            (0.0, 1.5), (0.0, 4.0), (0.0, 15.0), (0.5, 1.5), (1.0, 1.5))
        return tuple(
            {"specular_roughness": min(math.sqrt(a), 1.0), "specular_IOR": ior,
             **({} if self.dielectric else {"metalness": m})}
            for a in ALPHA_GRID
            for m, ior in rows
        )

    def eval_channels(self, params: Params, frame: Frame):
        m, metal, spec, throughput, diffuse = self.shading_terms(params, frame)
        return m * metal + (1.0 - m) * (spec + throughput[None] * diffuse)

    def shading_terms(self, params: Params, frame: Frame):
        """The pieces of ``f = m metal + (1 - m)(spec + T diffuse)``: the metalness
        ``m``, the conductor (3, ...), the dielectric's lobe (3, ...), its throughput T
        (...) and the diffuse (3, ...) under it, where a sheen layers
        (``standard_surface_sheen``)."""
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        terms = ggx_lobe_terms(specular_alpha(params["specular_roughness"]), frame)
        dv, ms_gain, cd = terms.dv, terms.ms_gain, terms.cos_d
        lobe, albedo = dielectric_lobe(params["specular_IOR"], terms)
        tint = params["specular_color"][expand]
        spec = tint * lobe[None]
        throughput = 1.0 - albedo

        # mx_oren_nayar_diffuse at roughness 0: A = 1, B = 0
        base = params["base_color"][expand]
        diffuse = base / jnp.pi

        n, k = artistic_ior(base, tint)
        # >= 0 as the formula is; the floor only catches rounding of an index of 1 at
        # V.H = 1e-8 (reflectivity 0: n = 1, k = 0), which renderer_terms' guards round
        # below 0 there
        f_c = jnp.maximum(conductor_fresnel(n, k, cd[None]), 0.0)
        metal = dv[None] * f_c * (1.0 + f_c * ms_gain[None])

        m = 0.0 if self.dielectric else params["metalness"]
        return m, metal, spec, throughput, diffuse

    def eval_frame(self, params: Params, frame: Frame):
        return jnp.moveaxis(self.eval_channels(params, frame), 0, -1)

    def start_candidates(self, table, usable: np.ndarray, kd: np.ndarray) -> np.ndarray:
        """Unconstrained starts, one per (specular_roughness, metalness, specular_IOR) on
        ``shape_grid``, each put on the measured highlight.

        At the peak bin (near normal incidence, where F ~ F0 and comp ~ 1) the lobe is
        ``F0 D G2 / (4 cos_i cos_o)``: the metal's reflectivity (``base_color``, also its
        edge colour: a flat Fresnel curve) is the excess over the diffuse floor divided
        by that lobe; the dielectric's ``specular_color`` the excess divided by
        ``F0(ior)`` times it, its base colour the diffuse estimate.
        """
        from brdffit.io.grid import bin_grid, peak_bin

        b = peak_bin(table, usable)
        g = bin_grid()
        frame = shading_frame(jnp.asarray(g.wi[b]), jnp.asarray(g.wo[b]))
        f_peak = table.rgb.reshape(3, -1)[:, b]
        excess = np.maximum(f_peak - kd / np.pi, 1e-3 * np.maximum(f_peak, 1e-6))
        starts = []
        for shape in self.shape_grid:
            m, ior = shape.get("metalness", 0.0), shape["specular_IOR"]
            lobe = max(float(ggx_dv(specular_alpha(shape["specular_roughness"]), frame)), 1e-12)
            reflectivity = np.clip(excess / lobe, 0.02, 0.98)
            f0 = ((ior - 1.0) / (ior + 1.0)) ** 2
            colour = np.clip(excess / (f0 * lobe), 0.02, 0.98)
            base = np.clip((1 - m) * kd + m * reflectivity, 0.02, 0.98)
            edge = (1 - m) * colour + m * reflectivity
            starts.append(self.unconstrain({
                "base_color": base, "specular_color": edge, **shape}))
        return np.stack(starts)
