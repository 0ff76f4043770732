"""Two GGX lobes over a Lambertian base, sharing one Schlick Fresnel term.

f = kd/pi + F(cos_d) * (ks1 DG(alpha1) + ks2 DG(alpha2)),
DG(alpha) = D_alpha G_alpha / (4 cos_i cos_o) (GGX, height-correlated Smith, see
microfacet.py), F = f0 + (1 - f0)(1 - cos_d)^5.

| name   | range      | meaning                                          |
|--------|------------|--------------------------------------------------|
| kd     | [0, inf)   | diffuse albedo, RGB                              |
| ks1    | [0, inf)   | scale of the first lobe, RGB                     |
| alpha1 | [1e-3, 2]  | roughness of the first lobe (log scale in a fit) |
| ks2    | [0, inf)   | scale of the second lobe, RGB                    |
| alpha2 | [1e-3, 2]  | roughness of the second lobe (log scale)         |
| f0     | [0, 1]     | Schlick reflectance at normal incidence          |

Measured coatings and metallic paints show a sharp highlight on a broad haze
(Ngan et al. 2005 fit two lobes for that reason). By convention lobe 1 is the
sharper one: fits start with alpha1 < alpha2, but nothing forces it, and a
single-lobe material is the degenerate case ks2 = 0.

Seeding: the two scales enter linearly, so instead of a fixed grid of ks values
(which could be off by decades) :meth:`GGX2.start_candidates` solves, for each
(alpha1, alpha2, f0) on ``shape_grid``, a small weighted least-squares problem
for (kd, ks1, ks2) on a few hundred bins of the table.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from brdffit.io.grid import bin_grid

from .base import KD, AbstractBRDFModel, ParamSpec
from .frame import Frame, shading_frame
from .ggx import GGX
from .microfacet import ALPHA_GRID, F0, schlick_fresnel

KS1 = ParamSpec("ks1", "scale of the first lobe (RGB; it starts as the sharper lobe, and may "
                       "end as the broader)", 0.0, None, rgb=True)
ALPHA1 = ParamSpec("alpha1", "roughness of the first lobe", 1e-3, 2.0, scale="log")
KS2 = ParamSpec("ks2", "scale of the second lobe (RGB)", 0.0, None, rgb=True)
ALPHA2 = ParamSpec("alpha2", "roughness of the second lobe", 1e-3, 2.0, scale="log")

_GGX = GGX()
#: Bins the seeding least squares looks at (a few hundred are plenty for 9 unknowns).
_SEED_BINS = 512


#: The new lobe's widths a fit from the parent's optimum starts at (ggx3's third over
#: ggx2, ggx4's fourth over ggx3), each beside the parent's lobes: sharper than a
#: mirror-like peak, at a glossy shoulder, at a haze (a third lobe started only sharper
#: than the first stayed at zero on chrome and tungsten-carbide). Its scale starts
#: small, but where the softplus has a slope.
NEW_LOBE_STARTS = (0.002, 0.006, 0.02, 0.06, 0.2, 0.6)
NEW_LOBE_SCALE = 0.01


def lobe_grid(alphas: tuple[str, ...]) -> tuple[dict, ...]:
    """Start shapes of a multi-lobe model: each lobe at least 3x broader than the one
    before on the microfacet roughness grid (closer pairs are one lobe twice), f0 below
    its bound (at the bound the sigmoid is flat and a fit could not leave it)."""
    def chains(k: int, above: float):
        if k == 0:
            yield ()
            return
        for a in ALPHA_GRID:
            if a >= 3.0 * above:
                for rest in chains(k - 1, a):
                    yield (a, *rest)

    return tuple({**dict(zip(alphas, chain, strict=True)), "f0": f0}
                 for chain in chains(len(alphas), 0.0) for f0 in (0.3, 0.95))


def new_lobe_scan(scale: str, alpha: str) -> tuple[dict, ...]:
    """``parent_scan`` of a model that adds lobe ``(scale, alpha)`` to its parent's: the
    new lobe at each of :data:`NEW_LOBE_STARTS`, at :data:`NEW_LOBE_SCALE`."""
    return tuple({alpha: a, scale: np.full(3, NEW_LOBE_SCALE)} for a in NEW_LOBE_STARTS)


class GGX2(AbstractBRDFModel):
    name = "ggx2"
    auto_candidate = True
    param_specs = (KD, KS1, ALPHA1, KS2, ALPHA2, F0)

    parent = "ggx"
    lobe_scales = ("ks1", "ks2")
    #: each lobe's roughness, in the order of ``lobe_scales``
    lobe_alphas = ("alpha1", "alpha2")
    shape_grid = lobe_grid(lobe_alphas)

    def unit_lobes(self, shape, frame: Frame):
        stacked = jnp.stack([*(shape[a] for a in self.lobe_alphas), shape["f0"]])
        return _lobes(stacked.astype(frame.cos_d.dtype), frame)

    def embed_parent(self, parent_params: dict) -> dict:
        """GGX as lobe 1, lobe 2 off (ks2 = 0) and three times broader, ready to grow."""
        alpha = float(np.asarray(parent_params["alpha"]))
        return {
            "kd": parent_params["kd"], "ks1": parent_params["ks"], "alpha1": alpha,
            "ks2": np.zeros(3), "alpha2": min(2.0, 3.0 * alpha), "f0": parent_params["f0"],
        }

    def eval_frame(self, params, frame: Frame):
        return jnp.moveaxis(self.eval_channels(params, frame), 0, -1)

    def eval_channels(self, params, frame: Frame):
        # channel-major (3, ...), the fitting loss's layout: colours broadcast, lobes once
        lobes = self.unit_lobes(params, frame)
        expand = (slice(None),) + (None,) * (lobes.ndim - 1)
        out = params["kd"][expand] / jnp.pi
        for scale, lobe in zip(self.lobe_scales, lobes, strict=True):
            out = out + params[scale][expand] * lobe[None]
        return out

    def start_candidates(self, table, usable: np.ndarray, kd: np.ndarray) -> np.ndarray:
        """Unconstrained start vectors (K, 12), one per ``shape_grid`` entry.

        Called by ``brdffit.fitting.starts.candidates``. ``kd`` (the diffuse
        estimate) is the fallback where the least squares leaves nothing.
        """
        g = bin_grid()
        # Away from grazing, where the lobes (not the Fresnel rise) make the values.
        sel = np.flatnonzero(usable & (g.cos_i > 0.3) & (g.cos_o > 0.3) & (g.theta_d < 0.6))
        if sel.size < 16:
            sel = np.flatnonzero(usable)
        # Flat order is theta_h-major with sqrt-spaced rows: a stride keeps the
        # bins dense near the peak, where a sharp lobe lives.
        sel = sel[:: max(1, sel.size // _SEED_BINS)]
        f_meas = table.rgb.reshape(3, -1)[:, sel].T  # (n, 3)
        alphas = np.array(sorted({s[k] for s in self.shape_grid for k in self.lobe_alphas}))
        f0s = np.array(sorted({s["f0"] for s in self.shape_grid}))
        # lobes[a, f, n]: F DG at the chosen bins for every alpha and f0 on the grid
        lobes = np.asarray(_lobes_at(jnp.asarray(alphas), jnp.asarray(f0s),
                                     jnp.asarray(g.wi[sel]), jnp.asarray(g.wo[sel])))
        # Relative residuals: the haze must count as much as the peak.
        w = 1.0 / np.maximum(f_meas.mean(axis=1), 1e-6)
        rows = {name: [] for name in ("kd", *self.lobe_scales, *self.lobe_alphas, "f0")}
        for shape in self.shape_grid:
            k = int(np.searchsorted(f0s, shape["f0"]))
            design = np.stack([np.full(sel.size, 1.0 / np.pi),
                               *(lobes[int(np.searchsorted(alphas, shape[a])), k]
                                 for a in self.lobe_alphas)], axis=1)
            coef, *_ = np.linalg.lstsq(design * w[:, None], f_meas * w[:, None], rcond=None)
            # A negative scale is no start. Floor it where the softplus still has a
            # slope (1e-3, not 1e-6): a lobe started at ~0 takes LM hundreds of steps.
            coef = np.clip(coef, 1e-3, 1e6)
            rows["kd"].append(coef[0] if np.any(coef[0] > 1e-3) else kd)
            for scale, c in zip(self.lobe_scales, coef[1:], strict=True):
                rows[scale].append(c)
            for name, v in shape.items():
                rows[name].append(v)
        return self.unconstrain_rows(rows)


@jax.custom_jvp
def _lobes(shape, frame: Frame):
    """(k, ...): F DG(alpha_i) for each lobe, for ``shape = (alpha_1, ..., alpha_k, f0)``."""
    fresnel = schlick_fresnel(shape[-1], frame.cos_d)
    return jnp.stack([fresnel * _GGX.shadowed_ndf(shape[i], frame)
                      for i in range(shape.shape[0] - 1)])


@functools.partial(_lobes.defjvp, symbolic_zeros=True)
def _lobes_jvp(primals, tangents):
    # Why: the fit's Jacobian pushes every parameter tangent through the model at once
    # (ggx2's 12, ggx3's 16), but the lobes depend on k + 1 of them (the colour tangents
    # are zero there). Forming the lobes' Jacobian in those inputs once and contracting
    # it with each tangent makes the fit's normal equations ~4x cheaper (exact).
    shape, frame = primals
    t_shape, t_frame = tangents
    value = _lobes.fun(shape, frame)
    tangent = jnp.zeros_like(value)
    if not isinstance(t_shape, SymbolicZero):
        jac = jax.jacfwd(_lobes.fun)(shape, frame)  # (k, ..., k + 1)
        tangent = tangent + jac @ t_shape
    frame_tangents = jax.tree_util.tree_leaves(t_frame)
    if not all(isinstance(t, SymbolicZero) for t in frame_tangents):  # d/d(directions)
        dense = jax.tree_util.tree_map(
            lambda t, p: jnp.zeros_like(p) if isinstance(t, SymbolicZero) else t,
            t_frame, frame, is_leaf=lambda t: isinstance(t, SymbolicZero),
        )
        tangent = tangent + jax.jvp(lambda fr: _lobes.fun(shape, fr), (frame,), (dense,))[1]
    return value, tangent


@eqx.filter_jit
def _lobes_at(alphas, f0s, wi, wo):
    frame = shading_frame(wi, wo)
    dg = jax.vmap(lambda a: _GGX.shadowed_ndf(a, frame))(alphas)  # (A, n)
    fresnel = jax.vmap(lambda f0: schlick_fresnel(f0, frame.cos_d))(f0s)  # (F, n)
    return dg[:, None, :] * fresnel[None, :, :]
