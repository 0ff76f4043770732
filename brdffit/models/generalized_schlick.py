"""A highlight whose colour turns with the angle: MaterialX's generalized Schlick over a diffuse.

As MaterialX 1.39.5's GLSL shades it.

The BRDF of ``layer(top = generalized_schlick_bsdf, base = oren_nayar_diffuse_bsdf)``
(``libraries/pbrlib``; distribution ggx, isotropic, no thin film, ``color82`` its default
white, the diffuse's roughness 0) for a direct light, evaluated as the GLSL generator
evaluates it (default options: analytic directional albedo). The lobe's Fresnel runs
from ``color0`` at normal incidence to ``color90`` at grazing along ``(1 - V.H)^exponent``;
with an ``exponent`` near 1 or 2 (Schlick's is 5) the colour turns across the angles a
picture sees, where a Schlick lobe stays one colour until grazing. Measured effect and
colour-changing paints turn so: color-changing-paint3's key-light sphere is reddish, its
grazing one greener (CIEDE2000 10 apart); ggx's mean colour there was 6.8 off, a lobe of
this Fresnel fitted to the same bins 4.4 (a numpy fit, 2026-12-06). In the terms of
``brdffit.models.standard_surface`` (the same D, V2, E and comp):

    F       = color0 + (color90 - color0) (1 - cos_d)^exponent   (mx_fresnel_hoffman_schlick,
              color82 white: its F82 term is 0)
    spec    = D V2 F comp(F)                          (mx_generalized_schlick_bsdf, weight 1)
    T       = 1 - mean over RGB of comp(F) (color0 A + color90 B)       (its throughput)
    f       = spec + T kd / pi          (mx_layer_bsdf over mx_oren_nayar_diffuse_bsdf)

| name     | range            | meaning (the MaterialX input)                          |
|----------|------------------|--------------------------------------------------------|
| kd       | [0, 1], RGB      | the diffuse's ``color``                                |
| color0   | [0, 1], RGB      | the lobe's reflectance at normal incidence (``color0``) |
| color90  | [0, 1], RGB      | its reflectance at grazing (``color90``)               |
| exponent | [0.2, 20] (log)  | the Fresnel curve's exponent (``exponent``; Schlick 5) |
| alpha    | [1e-3, 1] (log)  | GGX roughness (the BSDF's ``roughness``, both axes)    |

Only MaterialX has this lobe: glTF and Mitsuba files carry a Schlick Fresnel of one
exponent, and a fit of this model exports to them through a refit
(``brdffit.export``). Not reciprocal, as ``standard_surface`` is not (E, comp and T
read the view's cosine).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .base import AbstractBRDFModel, Params, ParamSpec
from .frame import Frame, shading_frame
from .guarded import safe_pow
from .microfacet import ALPHA_GRID
from .standard_surface import ggx_dv, ggx_lobe_terms

KD = ParamSpec("kd", "diffuse colour (the oren_nayar_diffuse_bsdf's color), RGB", 0.0, 1.0,
               rgb=True)
COLOR0 = ParamSpec("color0", "the lobe's reflectance at normal incidence, RGB", 0.0, 1.0,
                   rgb=True)
COLOR90 = ParamSpec("color90", "the lobe's reflectance at grazing incidence, RGB", 0.0, 1.0,
                    rgb=True)
EXPONENT = ParamSpec("exponent", "the Fresnel curve's exponent (Schlick's is 5)", 0.2, 20.0,
                     scale="log")
ALPHA = ParamSpec("alpha", "GGX roughness (the BSDF's roughness input)", 1e-3, 1.0,
                  scale="log")

#: Exponents a fit starts from: a colour that turns across the picture (1, 2), and
#: Schlick's own (5), where only the rim turns.
EXPONENT_STARTS = (1.0, 2.0, 5.0)


class GeneralizedSchlick(AbstractBRDFModel):
    name = "generalized_schlick"
    param_specs = (KD, COLOR0, COLOR90, EXPONENT, ALPHA)
    shape_grid = tuple({"alpha": a, "exponent": e}
                       for a in ALPHA_GRID if a <= 1.0 for e in EXPONENT_STARTS)

    def eval_channels(self, params: Params, frame: Frame):
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        terms = ggx_lobe_terms(jnp.clip(params["alpha"], 1e-8, 1.0), frame)
        c0, c90 = params["color0"][expand], params["color90"][expand]
        # MaterialX clamps V.H to [1e-8, 1] before the curve (terms.cos_d)
        curve = safe_pow(1.0 - terms.cos_d, params["exponent"])
        fresnel = c0 + (c90 - c0) * curve[None]
        comp = 1.0 + fresnel * terms.ms_gain[None]
        spec = terms.dv[None] * fresnel * comp
        albedo = comp * (c0 * terms.big_a[None] + c90 * terms.big_b[None])
        throughput = 1.0 - jnp.mean(albedo, axis=0)
        return spec + throughput[None] * params["kd"][expand] / jnp.pi

    def eval_frame(self, params: Params, frame: Frame):
        return jnp.moveaxis(self.eval_channels(params, frame), 0, -1)

    def start_candidates(self, table, usable: np.ndarray, kd: np.ndarray) -> np.ndarray:
        """Unconstrained starts, one per (alpha, exponent) on ``shape_grid``, each put on
        the measured highlight: at the peak bin (near normal incidence, F ~ color0) the
        lobe is ``color0 D V2``, so ``color0`` is the excess over the diffuse estimate
        divided by that; ``color90`` starts equal to it (a lobe of one colour, which the
        fit turns where the table does)."""
        from brdffit.io.grid import bin_grid, peak_bin

        b = peak_bin(table, usable)
        g = bin_grid()
        frame = shading_frame(jnp.asarray(g.wi[b]), jnp.asarray(g.wo[b]))
        f_peak = table.rgb.reshape(3, -1)[:, b]
        excess = np.maximum(f_peak - kd / np.pi, 1e-3 * np.maximum(f_peak, 1e-6))
        base = np.clip(kd, 0.0, 0.98)
        starts = []
        for shape in self.shape_grid:
            lobe = max(float(ggx_dv(shape["alpha"], frame)), 1e-12)
            colour = np.clip(excess / lobe, 0.005, 0.98)
            starts.append(self.unconstrain({"kd": base, "color0": colour, "color90": colour,
                                            **shape}))
        return np.stack(starts)
