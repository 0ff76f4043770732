"""The renderers' own microfacet terms: separable Smith GGX, the conductor Fresnel,
Burley's GTR1 (Disney's clear coat) and Cycles' Ashikhmin velvet.

The base models use the height-correlated Smith G (docs/models.md). Renderers do not:
the glTF 2.0 spec (Appendix B) and Mitsuba 3 (``microfacet.h``) both shade with the
separable product ``G = G1(wi) G1(wo)``, and Mitsuba's ``roughconductor`` with the
exact Fresnel of a conductor of complex index ``eta + i k``. The target models
(``gltf_pbr``, ``rough_conductor``) are built from these so that a fit of them is the
renderer's material, not an approximation of it.

- Separable Smith GGX: ``G1(w) = 2 cos_w / (cos_w + sqrt(cos_w^2 + alpha^2 sin_w^2))``
  (glTF's form; Mitsuba's ``2 / (1 + sqrt(1 + alpha^2 tan^2))`` is the same). With it

      D G / (4 cos_i cos_o) = D / ((cos_i + r_i) (cos_o + r_o)),  r = sqrt(cos^2 + alpha^2 sin^2)

  which has no cosine in a denominator: finite to grazing (r >= alpha sin > 0).
- Conductor Fresnel (Mitsuba 3 ``fresnel_conductor``, after Moeller, *Optics*, 1988),
  unpolarised, per channel, ``c = cos_d``, ``s2 = 1 - c^2``:

      t1 = eta^2 - k^2 - s2,   a2b2 = sqrt(t1^2 + 4 eta^2 k^2),   a = sqrt((a2b2 + t1) / 2)
      (in float32 without cancellation: see conductor_fresnel)
      Rs = (a2b2 + c^2 - 2 c a) / (a2b2 + c^2 + 2 c a)
         = ((c - a)^2 + e) / ((c + a)^2 + e),                 e = (a2b2 - t1) / 2 >= 0
      Rp = Rs (a2b2 c^2 + s2^2 - 2 c a s2) / (a2b2 c^2 + s2^2 + 2 c a s2)
         = Rs ((s2 - c a)^2 + c^2 e) / ((s2 + c a)^2 + c^2 e)
      F  = (Rs + Rp) / 2
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from .computed_once import computed_once
from .guarded import safe_div, safe_sqrt


def separable_ggx_dg(alpha, cos_h, sin2_h, cos_i, sin2_i, cos_o, sin2_o) -> Float[Array, ...]:
    """GGX ``D G1(wi) G1(wo) / (4 cos_i cos_o)`` (1/sr), the glTF / Mitsuba lobe without F."""
    a2 = alpha * alpha
    t = cos_h * cos_h * a2 + sin2_h  # cos^2 (a^2 - 1) + 1, without the cancellation
    d = a2 / (3.141592653589793 * t * t)
    return safe_div(d, separable_smith_denominator(alpha, cos_i, sin2_i, cos_o, sin2_o),
                    1e-30)


def separable_smith_denominator(alpha, cos_i, sin2_i, cos_o, sin2_o) -> Float[Array, ...]:
    """``(cos_i + r_i) (cos_o + r_o)`` = ``4 cos_i cos_o / (G1(wi) G1(wo))`` of separable
    Smith GGX at ``alpha`` (module docstring): what a lobe ``D`` is divided by."""
    a2 = alpha * alpha
    ri = safe_sqrt(cos_i * cos_i + a2 * sin2_i)
    ro = safe_sqrt(cos_o * cos_o + a2 * sin2_o)
    return (cos_i + ri) * (cos_o + ro)


def conductor_fresnel(eta, k, cos_d) -> Float[Array, ...]:
    """Unpolarised Fresnel reflectance of a conductor ``eta + i k`` (Mitsuba 3's formula).

    ``eta``, ``k`` broadcast against ``cos_d``. Both ratios have a denominator
    >= their numerator >= 0; it is 0 only for ``eta = 1, k = 0`` at grazing, where the
    floor returns the limit 0 (no reflection from a medium matched to the outside).

    Computed once and stored (``computed_once``): fused into what reads it, XLA
    computed it again per tangent of a solver's Jacobian (``standard_surface``'s
    Jacobian by per-parameter passes on 16,384 samples: 11.5 -> 7.2 ms).
    """
    return computed_once(lambda a: _conductor_fresnel(*a), (eta, k, cos_d), cos_d)


def _conductor_fresnel(eta, k, cos_d):
    c = cos_d
    s2 = 1.0 - c * c
    t1 = eta * eta - k * k - s2
    a2b2 = safe_sqrt(t1 * t1 + 4.0 * eta * eta * k * k)
    if jnp.result_type(a2b2) == jnp.float32:
        # a^2 = (a2b2 + t1) / 2 and excess = (a2b2 - t1) / 2, whose product is eta^2 k^2:
        # each from the sum that does not cancel, the other from the product. The
        # difference form cancels where |t1| >> eta k (eta < 1 and k ~ 0): in float32,
        # fused by XLA, it gave F = 0.57 for 1 on a rough_conductor fit of a real table
        # (its full-table log_rmse, evaluated in float32, twice the true one). In float64
        # it loses ~1e-8 of a and costs ~30% less per step, so the fit keeps it.
        positive = t1 >= 0.0
        big = 0.5 * (a2b2 + jnp.abs(t1))
        small = safe_div(eta * eta * k * k, big, 1e-30)
        a = safe_sqrt(jnp.where(positive, big, small))
        excess = jnp.where(positive, small, big)
    else:
        a = safe_sqrt(0.5 * (a2b2 + t1))
        excess = 0.5 * (a2b2 - t1)
    # Mitsuba's a2b2 + c^2 -+ 2 c a and a2b2 c^2 + s2^2 -+ 2 c a s2, regrouped as sums of
    # non-negative terms (a2b2 - a^2 = excess >= 0 in floating point too), so that
    # F >= 0 exactly where rounding made the difference form slightly negative (eta = 1,
    # k = 0, near grazing, times a sharp D).
    rs = safe_div((c - a) ** 2 + excess, (c + a) ** 2 + excess, 1e-30)
    rp = rs * safe_div((s2 - c * a) ** 2 + c * c * excess,
                       (s2 + c * a) ** 2 + c * c * excess, 1e-30)
    return 0.5 * (rs + rp)


def schlick_weight(cos) -> Float[Array, ...]:
    """Schlick's ``(1 - cos)^5``, the cosine clamped to [0, 1] (Cycles' and Mitsuba's
    ``schlick_fresnel`` / ``schlick_weight``)."""
    return jnp.clip(1.0 - cos, 0.0, 1.0) ** 5


def burley_diffuse(roughness, cos_i, cos_o, cos_d) -> Float[Array, ...]:
    """Burley's diffuse with its retro-reflection, pi f / base_color: ``(1 - Fi/2)(1 -
    Fo/2) + Rr (Fi + Fo + Fi Fo (Rr - 1))``, ``Rr = 2 roughness cos_d^2``: the
    principled BRDF's diffuse as Blender's Cycles (Principled BSDF v1) and Mitsuba's
    ``principled`` both evaluate it."""
    fi, fo = schlick_weight(cos_i), schlick_weight(cos_o)
    rr = 2.0 * roughness * cos_d * cos_d
    return (1.0 - 0.5 * fi) * (1.0 - 0.5 * fo) + rr * (fi + fo + fi * fo * (rr - 1.0))


def gtr1_d(alpha, cos_h) -> Float[Array, ...]:
    """Burley's GTR1 distribution (Disney's clear coat; Mitsuba's principled and Cycles'
    Principled v1 clearcoat): ``(a^2 - 1) / (pi log(a^2) (1 + (a^2 - 1) cos_h^2))``, its
    limit ``1 / pi`` at ``a = 1`` (as Cycles' ``D_GTR1`` returns there), with no NaN in
    either branch's gradient."""
    a2 = alpha * alpha
    flat = jnp.abs(a2 - 1.0) < 1e-6
    a2 = jnp.where(flat, 0.5, a2)
    d = (a2 - 1.0) / (jnp.pi * jnp.log(a2) * (1.0 + (a2 - 1.0) * cos_h * cos_h))
    return jnp.where(flat, 1.0 / jnp.pi, d)


#: Cycles' least velvet sigma (``bsdf_ashikhmin_velvet_setup``).
VELVET_MIN_SIGMA = 0.01
#: Cycles' velvet is zero within this of the normal (``|cos_h| < 1 - 1e-5``): sin^2
#: theta_h below ~2e-5.
VELVET_NORMAL_SIN2 = 1.0 - (1.0 - 1e-5) ** 2


def ashikhmin_velvet(sigma, cos_i, cos_o, cos_h, sin2_h, cos_d) -> Float[Array, ...]:
    """Cycles' Velvet BSDF (``bsdf_ashikhmin_velvet``), white, f_r (1/sr):

        D = exp(-cot^2 theta_h / s^2) / (pi s^2 sin^4 theta_h),   s = max(sigma, 0.01)
        G = min(1, 2 (cos_h / v.h) cos_o, 2 (cos_h / v.h) cos_i)
        f = D G / (4 cos_i cos_o)

    (``cos_h / v.h`` at least 1e-5), zero within Cycles' cutoff of the normal."""
    inv_s2 = 1.0 / jnp.maximum(sigma, VELVET_MIN_SIGMA) ** 2
    near_normal = sin2_h < VELVET_NORMAL_SIN2
    sin2 = jnp.where(near_normal, 1.0, sin2_h)
    cot2 = cos_h * cos_h / sin2
    d = jnp.exp(-cot2 * inv_s2) * inv_s2 / (jnp.pi * sin2 * sin2)
    ratio = jnp.maximum(cos_h / jnp.maximum(cos_d, 1e-5), 1e-5)
    # G / (4 cos_i cos_o) without a cosine in a denominator: min(1, 2 r cos_o, 2 r cos_i)
    # over 4 cos_i cos_o is min(1 / (4 cos_i cos_o), r / (2 cos_i), r / (2 cos_o))
    g_over = 0.5 * ratio / jnp.maximum(jnp.maximum(cos_i, cos_o), 1e-12)
    g_over = jnp.minimum(g_over, 0.25 / jnp.maximum(cos_i * cos_o, 1e-24))
    return jnp.where(near_normal, 0.0, d * g_over)
