"""MaterialX 1.39 standard_surface as MaterialX's GLSL shades it: a layered dielectric over Oren-Nayar, mixed with an artistic-IOR conductor.

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
    spec    = specular specular_color D V2 F_d comp(F_d)             (mx_dielectric_bsdf)
    T       = 1 - specular comp(F_d) (F0 A + B),  F0 = ((ior-1)/(ior+1))^2  (its throughput)
    diff    = base base_color ON(sigma = diffuse_roughness) / pi  (mx_oren_nayar_diffuse)
    n, k    = artistic_ior(base base_color, specular specular_color)  (mx_artistic_ior)
    metal   = D V2 F_c(cos_d; n, k) comp(F_c)            (mx_conductor_bsdf, mx_fresnel_conductor)
    f       = metalness metal + (1 - metalness) (spec + T diff)       (mix, layer)

``base`` and ``base_color`` enter only as their product (the diffuse colour and the
metal's reflectivity), so ``base`` is not fitted: it is 1 in the export and in the
model. The other inputs are MaterialX's names. ON is MaterialX's Oren-Nayar
(``A + B max(0, wi_xy . wo_xy) / max(cos_i, cos_o)``, sigma = ``diffuse_roughness``
in radians, as docs/models.md's ``oren_nayar``).

| name               | range              | meaning (MaterialX input)                                 |
|--------------------|--------------------|-----------------------------------------------------------|
| base_color         | [0, 1], RGB        | ``base_color``: diffuse colour; the metal's reflectivity  |
| metalness          | [0, 1]             | ``metalness``: mix weight of the conductor                |
| specular           | [0, 1]             | ``specular``: weight of the dielectric lobe (and edge tint) |
| specular_color     | [0, 1], RGB        | ``specular_color``: tint of the dielectric lobe; the metal's edge colour |
| specular_roughness | [0.0316, 1] (log)  | ``specular_roughness`` (alpha = roughness^2; bound: 1e-3) |
| specular_IOR       | [1, 3]             | ``specular_IOR``: the dielectric's index of refraction    |
| diffuse_roughness  | [0, 1]             | ``diffuse_roughness``: Oren-Nayar sigma (radians)         |

Not reciprocal: E and comp are functions of the view cosine (as MaterialX's are).
Where MaterialX clamps a cosine to 1e-8 (``M_FLOAT_EPS``) the model uses the
closed-form limit, and its Oren-Nayar term reads ``max(0, wi_xy . wo_xy)`` where
MaterialX reads ``max(L.V, 1e-8) - cos_i cos_o``: they differ only for
cos_i cos_o < 1e-8.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from .base import AbstractBRDFModel, Params, ParamSpec
from .frame import Frame
from .guarded import safe_div, safe_sqrt
from .microfacet import ALPHA_GRID, dielectric_fresnel
from .renderer_terms import conductor_fresnel

BASE_COLOR = ParamSpec("base_color", "base_color: diffuse colour and metal reflectivity (RGB)",
                       0.0, 1.0, rgb=True)
METALNESS = ParamSpec("metalness", "metalness: mix weight of the conductor", 0.0, 1.0)
SPECULAR = ParamSpec("specular", "specular: weight of the dielectric specular lobe", 0.0, 1.0)
SPECULAR_COLOR = ParamSpec("specular_color", "specular_color: specular tint, metal edge colour",
                           0.0, 1.0, rgb=True)
SPECULAR_ROUGHNESS = ParamSpec("specular_roughness", "specular_roughness (alpha = roughness^2)",
                               math.sqrt(1e-3), 1.0, scale="log")
SPECULAR_IOR = ParamSpec("specular_IOR", "specular_IOR: index of refraction of the dielectric",
                         1.0, 3.0)
DIFFUSE_ROUGHNESS = ParamSpec("diffuse_roughness", "diffuse_roughness: Oren-Nayar sigma",
                              0.0, 1.0)

#: The MaterialX ``standard_surface`` inputs the model sets, at MaterialX's defaults
#: where the model does not fit them (``base`` is folded into ``base_color``).
DEFAULTS = {"base": 1.0, "base_color": (0.8, 0.8, 0.8), "diffuse_roughness": 0.0,
            "metalness": 0.0, "specular": 1.0, "specular_color": (1.0, 1.0, 1.0),
            "specular_roughness": 0.2, "specular_IOR": 1.5}

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


class StandardSurface(AbstractBRDFModel):
    name = "standard_surface"
    param_specs = (BASE_COLOR, METALNESS, SPECULAR, SPECULAR_COLOR, SPECULAR_ROUGHNESS,
                   SPECULAR_IOR, DIFFUSE_ROUGHNESS)
    shape_grid = tuple(
        {"specular_roughness": min(math.sqrt(a), 1.0), "metalness": m}
        for a in ALPHA_GRID
        for m in (0.0, 0.5, 1.0)
    )

    def eval_channels(self, params: Params, frame: Frame):
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        # MaterialX clamps N.L, N.V, V.H to [1e-8, 1] (M_FLOAT_EPS)
        ci = jnp.maximum(frame.cos_i, 1e-8)
        co = jnp.maximum(frame.cos_o, 1e-8)
        cd = jnp.maximum(frame.cos_d, 1e-8)
        rough = params["specular_roughness"]
        alpha = jnp.clip(rough * rough, 1e-8, 1.0)
        a2 = alpha * alpha
        t = frame.cos_h * frame.cos_h * a2 + frame.sin2_h
        d = safe_div(a2, jnp.pi * t * t, 1e-30)
        lam_i = safe_sqrt(ci * ci + a2 * frame.sin2_i)
        lam_o = safe_sqrt(co * co + a2 * frame.sin2_o)
        dv = safe_div(d, 2.0 * (lam_i * co + lam_o * ci), 1e-30)  # D G2 / (4 cos_i cos_o)

        big_a, big_b = ggx_dir_albedo_ab(co, alpha)
        e_ss = big_a + big_b
        loss = safe_div(1.0 - e_ss, e_ss, 1e-6)  # (1 - E) / E

        ior = params["specular_IOR"]
        f_d = dielectric_fresnel(ior, cd)
        comp_d = 1.0 + f_d * loss
        f0 = ((ior - 1.0) / (ior + 1.0)) ** 2
        w_spec = params["specular"]
        tint = params["specular_color"][expand]
        spec = w_spec * tint * (dv * f_d * comp_d)[None]
        throughput = 1.0 - w_spec * (comp_d * (f0 * big_a + big_b))

        s2 = params["diffuse_roughness"] ** 2
        on_a = 1.0 - 0.5 * s2 / (s2 + 0.33)
        on_b = 0.45 * s2 / (s2 + 0.09)
        on = on_a + on_b * safe_div(jnp.maximum(frame.dot_xy, 0.0), jnp.maximum(ci, co), 1e-12)
        base = params["base_color"][expand]
        diffuse = base * (on / jnp.pi)[None]

        n, k = artistic_ior(base, w_spec * tint)
        f_c = conductor_fresnel(n, k, cd[None])
        metal = dv[None] * f_c * (1.0 + f_c * loss[None])

        m = params["metalness"]
        return m * metal + (1.0 - m) * (spec + throughput[None] * diffuse)

    def eval_frame(self, params: Params, frame: Frame):
        return jnp.moveaxis(self.eval_channels(params, frame), 0, -1)

    def start_candidates(self, table, usable: np.ndarray, kd: np.ndarray) -> np.ndarray:
        """Unconstrained starts, one per (specular_roughness, metalness) on ``shape_grid``.

        A dielectric start takes the diffuse estimate as its base colour, a metal's the
        peak bin's colour normalised to 0.9 (its reflectivity); the specular at
        MaterialX's defaults (weight 0.9, white, ior 1.5), diffuse roughness 0.1.
        """
        from brdffit.io.grid import peak_bin

        peak = table.rgb.reshape(3, -1)[:, peak_bin(table, usable)]
        metal = 0.9 * peak / max(float(np.max(peak)), 1e-12)
        starts = []
        for shape in self.shape_grid:
            m = shape["metalness"]
            base = np.clip((1 - m) * kd + m * metal, 0.02, 0.98)
            starts.append(self.unconstrain({
                "base_color": base, "specular": 0.9, "specular_color": np.full(3, 0.9),
                "specular_IOR": 1.5, "diffuse_roughness": 0.1, **shape}))
        return np.stack(starts)
