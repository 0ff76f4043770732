"""Mitsuba 3 rough plastic: a GGX dielectric interface over a diffuse base.

    f = ks F_d(cos_d; eta) D G1(wi) G1(wo) / (4 cos_i cos_o)
        + kd / (1 - R_int) * T(cos_i) T(cos_o) / (pi eta^2)

Mitsuba 3's ``roughplastic`` plugin (``distribution="ggx"``, ``nonlinear=false``), for a
dielectric exported as a dielectric (issue 42: a plastic or a fabric as a ``blendbsdf``
of a conductor and a diffuse looks plausible to nobody). ``F_d`` is the dielectric
Fresnel of the relative index ``eta`` (``int_ior / ext_ior``; the export writes
``ext_ior = 1``), the lobe Mitsuba's separable Smith GGX
(``brdffit.models.renderer_terms``). The diffuse base is seen through the
rough interface:

- ``T(mu)`` is the interface's transmittance at incidence ``cos = mu``, which Mitsuba
  tabulates at 64 cosines ``max(1e-6, j / 63)`` and interpolates linearly; each entry
  is its ``eval_transmittance``: a 32 x 32 Gauss-Legendre rule over the unit square,
  mapped to GGX's visible normals (Heitz's sampling of the distribution of visible
  normals, in Mitsuba's form: the concentric disk, the hemisphere projection), of
  ``G1(wt, m) (1 - F(wi.m))`` for the refracted ``wt``;
- ``R_int`` is the internal reflectance: twice the mean over the same 64 cosines of
  ``mu R(mu; 1 / eta)``, ``R`` the rough interface's reflectance from inside
  (``eval_reflectance``: 128 x 128 nodes, total internal reflection included).

Both are computed here from ``alpha`` and ``eta`` by the same rules, so the model is
Mitsuba's own to float32 rounding (``tests/test_export_tools.py`` checks it against
Mitsuba's ``BSDF.eval``), and a fit can move ``alpha`` and ``eta`` with exact
derivatives. The material conserves energy as Mitsuba's does.

| name  | range            | meaning                                               |
|-------|------------------|-------------------------------------------------------|
| kd    | [0, 1], RGB      | diffuse reflectance (Mitsuba ``diffuse_reflectance``) |
| alpha | [1e-3, 2] (log)  | GGX roughness (Mitsuba ``alpha``)                     |
| eta   | [1.001, 3]       | relative index of refraction (``int_ior``, ext 1)     |
| ks    | [0, 1], RGB      | specular scale (Mitsuba ``specular_reflectance``)     |

``ks`` is Mitsuba's optional factor on the specular lobe alone (the diffuse still sees
the whole interface): 1 is the physical interface. Fitted, it lets the highlight be
dimmer or tinted without moving the Fresnel curve: on white-acrylic the fit without it
ran ``eta`` down to 1.09, its highlight 1.74x the conductor mixture's error
(measured 2026-11-28).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from .base import AbstractBRDFModel, Params, ParamSpec
from .frame import Frame
from .guarded import safe_div, safe_sqrt
from .microfacet import ALPHA, ALPHA_GRID, dielectric_fresnel
from .renderer_terms import separable_ggx_dg

REFLECTANCE = ParamSpec("kd", "diffuse reflectance seen through the interface, RGB", 0.0, 1.0,
                        rgb=True)
#: Mitsuba refuses int_ior == ext_ior; just above 1 the interface reflects nothing
ETA = ParamSpec("eta", "relative index of refraction of the interface (int_ior)", 1.001, 3.0)
SPECULAR = ParamSpec("ks", "scale of the specular lobe (specular_reflectance), RGB", 0.0, 1.0,
                     rgb=True)

#: Mitsuba's MI_ROUGH_TRANSMITTANCE_RES: the cosines its transmittance table holds.
TABLE_SIZE = 64
#: Gauss-Legendre nodes per axis of eval_transmittance (eta > 1) and of
#: eval_reflectance from inside (eta < 1), as Mitsuba chooses them.
TRANSMITTANCE_NODES = 32
REFLECTANCE_NODES = 128
#: Mitsuba's floor of a microfacet roughness (MicrofacetDistribution::configure).
ALPHA_FLOOR = 1e-4


@functools.cache
def _square_rule(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes on the unit square (u1, u2) and their weights, as
    Mitsuba's ``(node + 1) / 2`` and ``w_x w_y / 4``, folded in half: the node
    ``u1 -> 1 - u1`` maps to the normal mirrored across the plane of incidence
    (the concentric disk's x turns sign, y stays), where both integrands take the
    same value (wi has no y), so the half with u1 < 1/2 counts twice (n is even).
    The sum is Mitsuba's to rounding, at half the cost."""
    x, w = np.polynomial.legendre.leggauss(n)
    u1, u2 = np.meshgrid(0.5 * (x + 1.0), 0.5 * (x + 1.0), indexing="ij")
    weight = np.outer(w, w) * 0.25
    half = n // 2
    return u1[:half].ravel(), u2[:half].ravel(), 2.0 * weight[:half].ravel()


def _table_cosines() -> np.ndarray:
    return np.maximum(1e-6, np.linspace(0.0, 1.0, TABLE_SIZE))


def _visible_normals(alpha, mu, u1, u2):
    """GGX visible normals m (3 arrays, shape (mu, node)) for ``wi = (sqrt(1 - mu^2), 0,
    mu)`` at the square's nodes ``u1, u2``: stretch wi, sample the alpha = 1 slopes by
    projecting the concentric disk onto the visible hemisphere, unstretch."""
    mu = mu[:, None]
    sin_i = jnp.sqrt(1.0 - mu * mu)
    stretched = jnp.sqrt(alpha * alpha * sin_i * sin_i + mu * mu)
    cos_t = mu / stretched
    sin_t = safe_sqrt(1.0 - cos_t * cos_t)
    # concentric map of the square onto the disk (Shirley and Chiu)
    x, y = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
    steep = np.abs(x) < np.abs(y)
    r = np.where(steep, y, x)
    phi = np.where(steep, 0.5 * np.pi - 0.25 * np.pi * x / y, 0.25 * np.pi * y / x)
    px, py = r * np.cos(phi), r * np.sin(phi)
    s = 0.5 * (1.0 + cos_t)
    py = safe_sqrt(1.0 - px * px) * (1.0 - s) + py * s
    pz = safe_sqrt(1.0 - px * px - py * py)
    norm = 1.0 / (sin_t * py + cos_t * pz)
    slope_x = (cos_t * py - sin_t * pz) * norm * alpha
    slope_y = px * norm * alpha
    length = jnp.sqrt(slope_x * slope_x + slope_y * slope_y + 1.0)
    return -slope_x / length, -slope_y / length, 1.0 / length, (sin_i, mu)


def _smith_g1(alpha, vx, vy, vz, m_dot_v):
    """Mitsuba's GGX G1 of direction v for microfacet normal m (0 where v sees m's back)."""
    tan2 = safe_div(alpha * alpha * (vx * vx + vy * vy), vz * vz, 1e-300)
    g1 = 2.0 / (1.0 + jnp.sqrt(1.0 + tan2))
    return jnp.where(m_dot_v * vz <= 0.0, 0.0, g1)


def _fresnel(cos_i, eta):
    """Mitsuba's unpolarised dielectric Fresnel for cos_i >= 0 and the transmitted
    cosine (negative; 0 under total internal reflection, where F = 1)."""
    cos_t2 = 1.0 - (1.0 - cos_i * cos_i) / (eta * eta)
    cos_t = safe_sqrt(cos_t2)
    a_s = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    a_p = (cos_t - eta * cos_i) / (cos_t + eta * cos_i)
    return 0.5 * (a_s * a_s + a_p * a_p), -cos_t


def transmittance_table(alpha, eta):
    """The interface's transmittance at the 64 table cosines (Mitsuba's
    ``eval_transmittance``, module docstring)."""
    u1, u2, w = _square_rule(TRANSMITTANCE_NODES)
    alpha = jnp.maximum(alpha, ALPHA_FLOOR)
    mx, my, mz, (ix, iz) = _visible_normals(alpha, _table_cosines(), u1, u2)
    c = ix * mx + iz * mz  # wi.m, wi = (ix, 0, iz)
    f, cos_t = _fresnel(c, eta)
    inv = 1.0 / eta
    scale = c * inv + cos_t  # refract: m (wi.m / eta + cos_t) - wi / eta
    tx, ty, tz = mx * scale - ix * inv, my * scale, mz * scale - iz * inv
    g1 = _smith_g1(alpha, tx, ty, tz, tx * mx + ty * my + tz * mz)
    value = jnp.where(tz * iz >= 0.0, 0.0, g1 * (1.0 - f))
    return value @ w


def internal_reflectance(alpha, eta):
    """Mitsuba's ``m_internal_reflectance``: 2 mean(mu R(mu; 1 / eta)) over the table's
    cosines, R the rough interface's reflectance from inside (``eval_reflectance``)."""
    u1, u2, w = _square_rule(REFLECTANCE_NODES)
    alpha = jnp.maximum(alpha, ALPHA_FLOOR)
    mu = _table_cosines()
    mx, my, mz, (ix, iz) = _visible_normals(alpha, mu, u1, u2)
    c = ix * mx + iz * mz
    f, _ = _fresnel(c, 1.0 / eta)
    ox, oy, oz = 2.0 * c * mx - ix, 2.0 * c * my, 2.0 * c * mz - iz  # reflect
    g1 = _smith_g1(alpha, ox, oy, oz, ox * mx + oy * my + oz * mz)
    value = jnp.where(oz <= 0.0, 0.0, g1 * f)
    return 2.0 * jnp.mean((value @ w) * mu)


@jax.custom_jvp
def interface_terms(alpha, eta):
    """(:func:`transmittance_table`, :func:`internal_reflectance`): what the diffuse
    base sees of the interface, a function of ``alpha`` and ``eta`` alone."""
    return transmittance_table(alpha, eta), internal_reflectance(alpha, eta)


@interface_terms.defjvp
def _interface_terms_jvp(primals, tangents):
    # Their ~1M quadrature points depend on two scalars: differentiated in those two
    # directions only, then combined, instead of once per fitted parameter (a fit's
    # forward-mode Jacobian carries 8 tangents; the kd and ks ones are zero here)
    alpha, eta = primals
    d_alpha, d_eta = tangents
    out = interface_terms(alpha, eta)
    # per output (table, r_int): its derivatives by (alpha, eta)
    jacobians = jax.jacfwd(
        lambda a, e: (transmittance_table(a, e), internal_reflectance(a, e)),
        argnums=(0, 1))(alpha, eta)
    return out, tuple(by_alpha * d_alpha + by_eta * d_eta for by_alpha, by_eta in jacobians)


def interpolate_table(table, cos):
    """Mitsuba's ``lerp_gather``: linear in the table at ``cos * 63``."""
    x = jnp.clip(cos, 0.0, 1.0) * (TABLE_SIZE - 1)
    index = jnp.minimum(jnp.floor(x), TABLE_SIZE - 2).astype(jnp.int32)
    t = x - index
    return table[index] * (1.0 - t) + table[index + 1] * t


class RoughPlastic(AbstractBRDFModel):
    name = "rough_plastic"
    param_specs = (REFLECTANCE, ALPHA, ETA, SPECULAR)
    shape_grid = tuple({"alpha": a, "eta": eta} for a in ALPHA_GRID for eta in (1.3, 1.5, 2.0))

    def eval_channels(self, params: Params, frame: Frame):
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        alpha, eta = params["alpha"], params["eta"]
        spec = dielectric_fresnel(eta, frame.cos_d) * separable_ggx_dg(
            jnp.maximum(alpha, ALPHA_FLOOR), frame.cos_h, frame.sin2_h,
            frame.cos_i, frame.sin2_i, frame.cos_o, frame.sin2_o)
        table, r_int = interface_terms(alpha, eta)
        through = (interpolate_table(table, frame.cos_i) * interpolate_table(table, frame.cos_o)
                   / (math.pi * eta * eta * (1.0 - r_int)))
        return params["ks"][expand] * spec[None] + params["kd"][expand] * through[None]

    def eval_frame(self, params: Params, frame: Frame):
        return jnp.moveaxis(self.eval_channels(params, frame), 0, -1)

    def start_candidates(self, table, usable: np.ndarray, kd: np.ndarray) -> np.ndarray:
        """Unconstrained starts, one per (alpha, eta) on ``shape_grid``; the diffuse
        estimate ``kd`` is the reflectance as it is (the interface's T^2 / (eta^2
        (1 - R_int)) is within 10% of 1 for eta 1.3-2)."""
        refl = np.clip(kd, 0.0, 0.98)
        return np.stack([self.unconstrain({**shape, "kd": refl, "ks": np.full(3, 0.98)})
                         for shape in self.shape_grid])
