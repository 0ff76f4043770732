"""A glTF material as three.js shades it for a direct light: ``gltf_threejs``.

The same three parameters as ``gltf_pbr`` (``base_color``, ``metallic``, ``roughness``:
the file's factors), evaluated as three.js r187's ``MeshStandardMaterial`` evaluates
them for a punctual light (``lights_physical_fragment``, ``RE_Direct_Physical``,
``BRDF_GGX``, ``lights_fragment_begin`` of its ShaderChunk). What differs from the
spec's definition (``gltf_pbr``), in order of size on rough reflective materials:

    r        = min(max(roughness, 0.045), 1),   alpha = r^2           (a roughness floor)
    f0       = mix(0.04, base_color, metallic)
    F        = f0 + (1 - f0) Fs,   Fs = 2^((-5.55473 c - 6.98316) c)  (Schlick, exp2 form)
    V        = 0.5 / (cos_i sqrt(a2 + (1 - a2) cos_o^2) + cos_o sqrt(a2 + (1 - a2) cos_i^2))
                                                                (height-correlated Smith)
    specular = F D V (1 + f0 (1/Ess - 1))       (multiple-scattering compensation)
    diffuse  = base_color (1 - metallic) / pi (1 - F_d),   F_d = 0.04 + 0.96 Fs
    f        = specular + diffuse

with ``c = v.h``, ``a2 = alpha^2``, D the GGX distribution and ``Ess(r, cos_o)`` the
directional albedo of the white single-scattering lobe, which three.js reads from a
16 x 16 table (``DFGLUTData.js``: scale + bias at texel centres, bilinear). Here the
table is computed from its definition (:func:`ess_table`, a quadrature over the GGX
half-vector distribution) and read the same way; ``tests/test_export_viewers.py``
checks it against three.js's own table and the whole model against three.js's
render. Not modelled: three.js adds a screen-space term to the roughness (the
normal's change per pixel, ~0.01 at the centre of a 256-px sphere, more at its rim).

| name       | range              | meaning                                        |
|------------|--------------------|------------------------------------------------|
| base_color | [0, 1], RGB        | ``baseColorFactor`` (linear RGB)               |
| metallic   | [0, 1]             | ``metallicFactor``                             |
| roughness  | [0.0316, 1] (log)  | ``roughnessFactor`` (three.js shades it at 0.045 or more) |
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from .base import Params
from .frame import Frame
from .gltf_pbr import DIELECTRIC_F0, GltfPBR

#: three.js's least roughness for a punctual light (``BRDF_GGX``).
MIN_ROUGHNESS = 0.045
#: Texels per side of three.js's DFG table (roughness across, cos_o down).
LUT_SIZE = 16
#: three.js's EPSILON (common.glsl), the floor of V's denominator.
EPSILON = 1e-6


def schlick_exp2(c):
    """Schlick's (1 - c)^5 as three.js computes it (Epic's exp2 fit, ``F_Schlick``)."""
    return jnp.exp2((-5.55473 * c - 6.98316) * c)


def threejs_fresnel(f0, c):
    """three.js's ``F_Schlick(f0, 1, c)``: ``f0 (1 - Fs) + Fs``, Fs its exp2 form."""
    fs = schlick_exp2(c)
    return f0 * (1.0 - fs) + fs


@functools.cache
def ess_table(nodes: int = 64) -> np.ndarray:
    """Ess at the table's texel centres, (cos_o, roughness) = ((j + 0.5)/16, (i + 0.5)/16),
    rows cos_o: the albedo of the white single-scattering lobe ``D V`` (F = 1) seen from
    cos_o. The half vector is drawn from D(h) cos_h exactly (the GGX inverse CDF on
    Gauss-Legendre nodes, ``nodes`` x ``nodes``), so that a near-mirror lobe is
    integrated as well as a rough one:

        Ess = E[ V cos_i 4 (v.h) / cos_h ],   l = 2 (v.h) h - v."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    t, wt = (x + 1) / 2, w / 2  # on [0, 1]
    phi = (np.arange(nodes) + 0.5) / nodes * 2 * np.pi
    centres = (np.arange(LUT_SIZE) + 0.5) / LUT_SIZE
    mu = centres[:, None, None, None]  # cos_o, rows
    alpha = (centres ** 2)[None, :, None, None]  # roughness^2, columns
    a2 = alpha * alpha
    tt = t[None, None, :, None]
    cos_h = np.sqrt((1 - tt) / (1 + (a2 - 1) * tt))
    sin_h = np.sqrt(np.maximum(1 - cos_h * cos_h, 0.0))
    v = (np.sqrt(1 - mu * mu), 0.0, mu)
    h = (sin_h * np.cos(phi), sin_h * np.sin(phi), cos_h)
    vh = v[0] * h[0] + v[1] * h[1] + v[2] * h[2]
    cos_i = 2 * vh * h[2] - v[2]
    ok = (vh > 0) & (cos_i > 0)
    ci = np.where(ok, cos_i, 0.0)
    vis = 0.5 / np.maximum(ci * np.sqrt(a2 + (1 - a2) * mu * mu)
                           + mu * np.sqrt(a2 + (1 - a2) * ci * ci), EPSILON)
    g = np.where(ok, vis * ci * 4 * vh / cos_h, 0.0)
    return np.einsum("ijtp,t->ij", g, wt) / nodes


def lut_bilinear(table, r, mu):
    """three.js's ``texture2D(dfgLUT, vec2(r, mu))``: bilinear between texel centres,
    clamped to the edge texels (table rows mu, columns r)."""
    n = table.shape[0]
    x = jnp.clip(r * n - 0.5, 0.0, n - 1.0)
    y = jnp.clip(mu * n - 0.5, 0.0, n - 1.0)
    x0 = jnp.clip(jnp.floor(x), 0, n - 2).astype(jnp.int32)
    y0 = jnp.clip(jnp.floor(y), 0, n - 2).astype(jnp.int32)
    fx, fy = x - x0, y - y0
    t = jnp.asarray(table)
    top = t[y0, x0] * (1 - fx) + t[y0, x0 + 1] * fx
    bottom = t[y0 + 1, x0] * (1 - fx) + t[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


def ggx_vd(r, nl, nv, nh):
    """three.js's ``V_GGX_SmithCorrelated`` times ``D_GGX`` at roughness ``r`` (its
    alpha = r^2): the specular lobe of ``BRDF_GGX`` and ``BRDF_GGX_Clearcoat`` without
    their Fresnel."""
    a2 = (r * r) ** 2
    vis = 0.5 / jnp.maximum(nl * jnp.sqrt(a2 + (1.0 - a2) * nv * nv)
                            + nv * jnp.sqrt(a2 + (1.0 - a2) * nl * nl), EPSILON)
    denom = nh * nh * (a2 - 1.0) + 1.0
    return vis * a2 / (jnp.pi * denom * denom)


def screen_roughness(roughness, geometry_roughness):
    """The roughness three.js shades a pixel with (``lights_physical_fragment``): the
    factor at least :data:`MIN_ROUGHNESS`, plus the normal's change to the next pixel
    (``geometryRoughness``), at most 1; the model itself takes the factor alone."""
    return jnp.minimum(jnp.maximum(roughness, MIN_ROUGHNESS) + geometry_roughness, 1.0)


class GltfThreejs(GltfPBR):
    """``gltf_pbr``'s parameters as three.js shades them (module docstring)."""

    @property
    def name(self) -> str:
        return "gltf_threejs"

    @property
    def parent(self) -> str | None:
        return None

    def eval_channels(self, params: Params, frame: Frame):
        fresnel, lobe, compensation, diffuse = self.shading_terms(params, frame)
        return fresnel * lobe * compensation + diffuse

    def shading_terms(self, params: Params, frame: Frame):
        """three.js's pieces of ``f = F (D V) compensation + diffuse``: the specular
        Fresnel F at v.h (3, ...), the lobe ``D V`` (1, ...), the multiple-scattering
        compensation (3, ...) and the diffuse (3, ...). A thin film
        (``gltf_threejs_iridescence``) replaces F alone, as three.js's ``BRDF_GGX``
        does."""
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        base, m = params["base_color"][expand], params["metallic"]
        r = jnp.clip(params["roughness"], MIN_ROUGHNESS, 1.0)
        nv = frame.cos_o
        f0 = DIELECTRIC_F0 * (1.0 - m) + base * m
        fresnel = threejs_fresnel(f0, frame.cos_d[None])
        ess = lut_bilinear(ess_table(), r, nv)
        compensation = 1.0 + f0 * (1.0 / ess - 1.0)[None]
        lobe = ggx_vd(r, frame.cos_i, nv, frame.cos_h)[None]
        fresnel_d = threejs_fresnel(DIELECTRIC_F0, frame.cos_d[None])
        diffuse = base * (1.0 - m) / jnp.pi * (1.0 - fresnel_d)
        return fresnel, lobe, compensation, diffuse
