"""The fitting losses, and the compressions that the error metrics share with them.

Residual of bin b, channel c, for a loss with compression ``g``:

    r_cb = sqrt(w_b) * ( g(f_model_c(b) cos_i(b)) - g(f_meas_c(b) cos_i(b)) )

The loss is a choice (:data:`LOSS_REGISTRY`, docs/fitting.md says when to use which):

- ``"log"`` (default): ``g(x) = log(1 + x)``, after Löw et al. 2012 and Ngan et
  al. 2005, who fit in a log space so that the peak does not swamp the rest;
- ``"cube_root"``: ``g(x) = cbrt(x + 1e-6)``, the perceptual compression of
  Löw et al. 2012 and Sun et al. 2018 (closer to lightness than the log; the
  highlight counts more than under the log, less than in linear space). The
  offset keeps the slope finite at ``x = 0`` (``cbrt`` has an infinite one there);
  it cancels in every difference of values well above 1e-6 1/sr;
- ``"linear_cos"``: ``g(x) = x``, the linear radiance-like error under uniform
  lighting: the energy of the highlight decides, as in a rendered image without
  tone mapping;
- ``"render"``: ``g_c(x) = tone(e_c x)``, the error of rendered views after a
  smooth tone curve (:func:`tone`), with one exposure ``e_c`` per channel taken
  from the table (``LossData.exposure``, data, not static) and bin weights that
  count how often each bin is seen over sphere renders under several lights
  (``brdffit.fitting.render_loss``, docs/fitting.md); plus three residuals that
  hold each channel's mean radiance over the views (:func:`energy_residuals`).

with w_b the bin's solid-angle weight (see ``brdffit.io.grid``; times the scene
weight for scene-aware fits), normalised to sum 1 over the bins used. Only
measured, finite bins above the horizon have w_b > 0.

``log_rmse`` is the root of the weighted mean square of the bracket under the log
loss (``cube_root_rmse`` and ``rmse_cos`` the same under the other two):

    log_rmse = sqrt( sum_b w_b sum_c (...)^2 / (3 sum_b w_b) )

evaluated over **all** usable bins of the table (not just the fit's subsample), or
every usable sample of a sample list, by ``brdffit.fitting.problem.error_sums`` (the one
implementation of the metrics).

Arrays are channel-major, (3, S), like the MERL file: XLA vectorises along the
long bin axis, which makes the loss ~3x cheaper than bin-major (S, 3) arrays.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from types import MappingProxyType, ModuleType
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from brdffit.errors import FitInputError
from brdffit.fitting.options import DEFAULT_LOSS, LOSSES
from brdffit.models import AbstractBRDFModel
from brdffit.models.base import ParamSpec
from brdffit.models.frame import Frame

# LOSSES and DEFAULT_LOSS, the names, are declared with the other options
# (``brdffit.fitting.options``, which imports no JAX); each loss is a :class:`Loss`
# of :data:`LOSS_REGISTRY`, below.
#: Offset inside the cube root (1/sr, times cos_i): finite slope at 0, far below
#: any measured value (``merl.MIN_PEAK`` is 1e-5 for the brightest bin).
CUBE_ROOT_OFFSET = 1e-6


#: The tone curve of the render loss (:func:`tone`): Reinhard's ``y / (1 + y)``, then
#: a display gamma whose toe is offset by TONE_TOE so that its slope stays finite at 0
#: (the sRGB curve's linear toe, without its kink).
TONE_GAMMA = 1 / 2.2
TONE_TOE = 0.003
_TOE_P = TONE_TOE**TONE_GAMMA
_TONE_NORM = (1.0 + TONE_TOE) ** TONE_GAMMA - _TOE_P


def tone(y, xp=jnp):
    """The render loss's smooth tone curve of exposed radiance ``y >= 0``, in [0, 1):
    ``((v + t)^gamma - t^gamma) / ((1 + t)^gamma - t^gamma)`` of ``v = y / (1 + y)``,
    ``t`` = :data:`TONE_TOE`. Nothing clips: a highlight 100x the exposure still
    differs from one 50x it (~0.4% of the range)."""
    v = y / (1.0 + y)
    return (xp.exp(xp.log(v + TONE_TOE) * TONE_GAMMA) - _TOE_P) / _TONE_NORM


def tone_slope(y):
    """``d tone / dy`` (``y >= 0``), for the closed-form Jacobian."""
    v = y / (1.0 + y)
    return TONE_GAMMA * jnp.exp(jnp.log(v + TONE_TOE) * (TONE_GAMMA - 1.0)) / (
        _TONE_NORM * (1.0 + y) ** 2)


def tone_inverse(t, xp=jnp):
    """The exposed radiance whose :func:`tone` is ``t`` (0 <= t < 1)."""
    v = xp.exp(xp.log(t * _TONE_NORM + _TOE_P) / TONE_GAMMA) - TONE_TOE
    v = xp.clip(v, 0.0, 1.0 - 1e-12)
    return v / (1.0 - v)


def _cbrt(x, xp=jnp):
    # exp(log(x)/3) for x > 0: XLA's CPU cbrt is ~20x slower over a full table, and
    # this agrees with it to 1e-6 relative in float32
    return xp.exp(xp.log(x) * (1.0 / 3.0))


@dataclass(frozen=True)
class Loss:
    """One loss a fit can minimise: its compression ``g`` of ``x = f cos_i >= 0`` (the
    module docstring), ``g'`` for the closed-form Jacobian, ``g``'s inverse, the
    metric that reports it, and whether it brings data of its own."""

    name: str
    #: the metric that the loss is the (weighted) mean square of
    #: (``brdffit.fitting.problem.metrics_from_sums``); ``full_table``: reported by
    #: every fit, whatever it optimised, over every usable bin. The render loss is
    #: defined on its views: results report ``sample_render_rmse`` on the solver's
    #: subsample, and the sphere's ``psnr_db``.
    metric: str
    #: ``g(x, xp)``, ``xp`` the array module (numpy for targets made in numpy); the
    #: caller clamps ``x`` at 0, so that the hot path holds no second clamp
    compress: Callable
    #: ``g'(x)``
    slope: Callable
    #: ``g^-1(t, exposure)``: the ``f cos_i`` whose compression is ``t``
    uncompress: Callable
    full_table: bool = True
    #: the loss compares rendered views (``brdffit.fitting.render_loss``): each
    #: channel's exposure multiplies ``x`` before ``g`` and an energy term holds each
    #: channel's mean (:func:`energy_residuals`), data per table made from its values
    #: in numpy; the solver's bins are the views' unless a scene says otherwise
    rendered: bool = False
    #: the array module that compresses a table's measured targets. numpy for the
    #: log loss: the same targets, to the last bit, as before the loss was a choice
    #: (JAX's log1p differs in the last place on some values). The cube root's in
    #: JAX, as the fit compresses its own values, and as they have been made since
    #: it was added.
    target_xp: ModuleType = jnp

    @property
    def selectable(self) -> bool:
        """One elementwise compression with no data of its own: a fit's compiled
        programs serve every such loss, the choice being data
        (``LossData.selector``, :data:`SELECTED`), so another of them costs a fit,
        not a compile."""
        return not self.rendered


def _cube_root_slope(x):
    c = _cbrt(x + CUBE_ROOT_OFFSET)
    return 1.0 / (3.0 * c * c)


def _render_uncompress(t, exposure):
    return tone_inverse(t) / exposure


#: Every loss by name, in the order of ``options.LOSSES`` (tests/test_registries.py
#: checks they agree). A selectable loss's place among :data:`SELECTABLE` is its
#: ``LossData.selector``.
LOSS_REGISTRY = MappingProxyType({loss.name: loss for loss in (
    Loss("log", "log_rmse",
         compress=lambda x, xp=jnp: xp.log1p(x),
         slope=lambda x: 1.0 / (1.0 + x),
         uncompress=lambda t, exposure=None: jnp.expm1(t),
         target_xp=np),
    Loss("cube_root", "cube_root_rmse",
         compress=lambda x, xp=jnp: _cbrt(x + CUBE_ROOT_OFFSET, xp),
         slope=_cube_root_slope,
         uncompress=lambda t, exposure=None: jnp.maximum(t**3 - CUBE_ROOT_OFFSET, 0.0)),
    Loss("linear_cos", "rmse_cos",
         compress=lambda x, xp=jnp: x,
         slope=jnp.ones_like,
         uncompress=lambda t, exposure=None: t),
    # x already times the channel's exposure (:func:`exposed`)
    Loss("render", "render_rmse",
         compress=lambda x, xp=jnp: tone(x, xp),
         slope=tone_slope,
         uncompress=_render_uncompress,
         full_table=False, rendered=True, target_xp=np),
)})


def get_loss(name: str) -> Loss:
    """The loss ``name`` of :data:`LOSS_REGISTRY`; :class:`FitInputError` naming the
    choices for any other name."""
    try:
        return LOSS_REGISTRY[name]
    except KeyError:
        raise FitInputError(f"unknown loss {name!r}; choose one of {', '.join(LOSSES)}") from None


#: loss -> the metric that reports it: every result reports those of the
#: ``full_table`` losses, whatever was optimised.
LOSS_METRIC = {name: loss.metric for name, loss in LOSS_REGISTRY.items()}
#: The losses of every fit's full-table metrics, in the order of their sums
#: (``brdffit.fitting.problem.error_sums``).
FULL_TABLE_LOSSES = tuple(name for name, loss in LOSS_REGISTRY.items() if loss.full_table)
#: The :attr:`Loss.selectable` losses: ``LossData.selector`` indexes them.
SELECTABLE = tuple(name for name, loss in LOSS_REGISTRY.items() if loss.selectable)
#: ``LossData.loss`` of data whose loss is one of :data:`SELECTABLE`, chosen by its
#: ``selector`` at run time (``lax.switch``: only the chosen branch runs).
SELECTED = "selected"


def compress_values(x, loss: str, selector=None):
    """``g(x)`` of the module docstring, for ``x = f cos_i >= 0``: the caller clamps
    (``compress`` does), so that the hot path holds no second clamp. ``loss`` may be
    :data:`SELECTED`, the loss then being ``SELECTABLE[selector]``."""
    if loss == SELECTED:
        return jax.lax.switch(selector, [LOSS_REGISTRY[n].compress for n in SELECTABLE], x)
    return get_loss(loss).compress(x)


def compress_slope(x, loss: str, selector=None):
    """``g'(x)``, for the closed-form Jacobian of :func:`normal_equations` (``x >= 0``)."""
    if loss == SELECTED:
        return jax.lax.switch(selector, [LOSS_REGISTRY[n].slope for n in SELECTABLE], x)
    return get_loss(loss).slope(x)


def compress_with_slope(x, loss: str, selector=None):
    """``(g(x), g'(x))`` in one branch: a :data:`SELECTED` loss switches once."""
    if loss == SELECTED:
        return jax.lax.switch(selector, [lambda v, n=n: compress_with_slope(v, n)
                                         for n in SELECTABLE], x)
    return compress_values(x, loss), compress_slope(x, loss)


class LossData(eqx.Module):
    """One fixed-size batch of bins: geometry, compressed targets, weights, and the
    loss they are compressed for (static: each loss compiles its own fit), or
    :data:`SELECTED` with the loss in ``selector`` (data: one fit for them all)."""

    frame: Frame  # per-bin geometry, precomputed (see brdffit.models.frame), (S,)
    target: Float[Array, "3 s"]  # g(f_meas * cos_i) of the loss
    weight: Float[Array, " s"]  # sums to 1; 0 on padding and unusable bins
    loss: str = eqx.field(static=True, default=DEFAULT_LOSS)
    # the render loss's exposure per channel (times f cos_i before the tone curve);
    # None for the other losses. Data, not static: one compiled fit for every table.
    exposure: Float[Array, "3 1"] | None = None
    # the render loss's measured mean radiance per channel over the views (the
    # weighted mean of f cos_i), which the fit's must hold (:func:`energy_residuals`)
    energy: Float[Array, "3 1"] | None = None
    # the index into SELECTABLE of the loss, where ``loss`` is SELECTED
    selector: Int[Array, ""] | None = None

    @property
    def loss_name(self) -> str:
        """The loss the targets are compressed for, whether static or selected (on
        concrete data only: a traced selector has no value)."""
        return SELECTABLE[int(self.selector)] if self.loss == SELECTED else self.loss


#: Weight of the render loss's colour-holding term: the residual of channel c is
#: sqrt(ENERGY_WEIGHT) * log(mean fitted f cos_i / mean measured f cos_i) over the
#: views, beside the per-bin tone-mapped residuals (whose sum of squares is ~1e-3
#: for a fit that looks right). The tone curve alone lets a glossy fit lose most of
#: its highlight's energy (a highlight at 30x or 300x the exposure looks alike), and
#: with it the material's colour and brightness as a whole. Tuned on the design half
#: of the MERL set (bench/render_loss.py --half design; docs/fitting.md): at 0.01,
#: two materials' colours regressed against the log loss (black-obsidian by CIEDE2000
#: 6, red-metallic-paint 2.4); 0.05 holds them at the same median gain (+3.66 dB
#: against +3.69), 0.2 gives some of it back (+3.63).
ENERGY_WEIGHT = 0.05

def exposed(x, exposure):
    """``x`` times the per-channel exposure, where the loss has one."""
    return x if exposure is None else x * exposure


def compress(
    f: Float[Array, "3 s"], cos_i: Float[Array, " s"], loss: str = DEFAULT_LOSS, exposure=None,
    selector=None,
) -> Float[Array, "3 s"]:
    """The compressed value g(f cos_i) that the loss compares."""
    return compress_values(exposed(jnp.maximum(f, 0.0) * jnp.maximum(cos_i, 0.0), exposure),
                           loss, selector)


def residuals(u: Float[Array, " p"], args) -> Float[Array, "3 s"]:
    """Per-sample residuals (3, S); with the render loss's energy term, (3, S + 1):
    the last column is :func:`energy_residuals`."""
    model, data = args
    return residuals_of_params(model.constrain(u), model, data)


def residuals_of_params(params: dict, model, data) -> Float[Array, "3 s"]:
    """:func:`residuals` at the parameters themselves."""
    f = model.eval_channels(params, data.frame)
    r = _compared(f, data)
    if data.energy is None:
        return r
    total = jnp.maximum(f, 0.0) @ (data.weight * jnp.maximum(data.frame.cos_i, 0.0))
    return jnp.concatenate([r, energy_residuals(total, jnp.sum(data.weight), data)[:, None]],
                           axis=1)


def _sample_residuals_of_params(params: dict, model, data):
    return _compared(model.eval_channels(params, data.frame), data)


def _compared(f, data):
    return jnp.sqrt(data.weight) * (
        compress(f, data.frame.cos_i, data.loss, data.exposure, data.selector) - data.target)


#: The render loss's colour-holding term compares a channel's mean no lower than this
#: fraction of the table's brightest channel's: any mean below it is as black as the
#: next. Without it, a black channel (a pure red table's G and B, 0 in every bin) asked
#: the fit to bring its mean to 1e-30 in log space, a pull without end that bent the
#: shared lobe (alpha, f0) to its bounds: a wrong fit reported successful and good.
#: The darkest channel of every MERL material holds >= 6% of the brightest's energy.
ENERGY_FLOOR = 1e-3


def _energy_floor(data):
    return jnp.maximum(ENERGY_FLOOR * jnp.max(data.energy), 1e-30)


def energy_residuals(total, weight_sum, data):
    """The colour-holding residual per channel (3,): ``sqrt(ENERGY_WEIGHT) log(M_c /
    M*_c)``, ``M_c = total_c / weight_sum`` the fit's weighted mean of ``f cos_i``, both
    means at least :data:`ENERGY_FLOOR` of the table's brightest channel's."""
    floor = _energy_floor(data)
    mean = jnp.maximum(total / weight_sum, floor)
    return jnp.sqrt(ENERGY_WEIGHT) * (jnp.log(mean) - jnp.log(jnp.maximum(data.energy[:, 0],
                                                                        floor)))


def _energy_sums(u, model, data):
    """(sum_s w_s f_c cos_i (3,), its derivative in ``u`` (3, p)) over ``data``'s
    samples: closed form for a colour-linear model (as :func:`_normal_equations`),
    else :func:`jacobian_of_params`."""
    wc = data.weight * jnp.maximum(data.frame.cos_i, 0.0)
    layout = _colour_layout(model)
    if layout is None:
        return jacobian_of_params(
            lambda params: jnp.maximum(model.eval_channels(params, data.frame), 0.0) @ wc,
            u, model)
    p = _colour_parts(u, model, data.frame, layout)
    total = p.f @ wc  # (3,)
    colour = p.slope.T * (p.basis @ wc)[None, :]  # (3, K+1)
    shape = jnp.einsum("jcs,s->cj", p.shape_cols, wc)  # (3, J)
    grad = jnp.zeros((3, u.size), u.dtype)
    grad = grad.at[np.arange(3)[:, None], layout.colour_at].set(colour)
    grad = grad.at[:, layout.shape_at].set(shape)
    return total, grad


def sum_squares(u, model: AbstractBRDFModel, data: LossData):
    r = residuals(u, (model, data))
    return jnp.sum(r * r)


#: Samples per block of the normal equations (see :func:`normal_equations`).
BLOCK = 16384


def normal_equations(u: Float[Array, " p"], args, meat: bool = False):
    """(sum r^2, J^T J, J^T r) of :func:`residuals`, for the solver's step; with
    ``meat`` also sum_i r_i^2 J_i^T J_i, the meat of the sandwich covariance
    (``brdffit.fitting.uncertainty``): the solver carries it at its current point,
    so that a fit's uncertainty needs no program of its own.

    Every term is a sum over the samples, so a large sample set (every bin of a
    table: 1.46M) is summed block by block (:data:`BLOCK` samples at a time, a
    divisor of the sample count near it): each block's temporaries stay in the
    CPU's cache instead of streaming ~20 arrays of 1.46M x 3 through memory,
    which makes a full-table step ~3x cheaper per sample than one pass. A sample
    count with no such divisor is summed in one pass.
    """
    model, data = args
    if data.energy is None:
        return sum_over_blocks(lambda part: _normal_equations(u, model, part, meat), data)
    sums, (total, grad) = sum_over_blocks(
        lambda part: (_normal_equations(u, model, part, meat), _energy_sums(u, model, part)),
        data)
    rho, g = _energy_rows(total, grad, data)
    loss, jtj, jtr = sums[:3]
    out = (loss + jnp.sum(rho * rho), jtj + g.T @ g, jtr + g.T @ rho)
    return out + ((sums[3] + (g * (rho * rho)[:, None]).T @ g,) if meat else ())


def normal_equations_with_meat(u: Float[Array, " p"], args):
    """:func:`normal_equations` with the sandwich's meat: (sum r^2, J^T J, J^T r, meat)."""
    return normal_equations(u, args, meat=True)


def _energy_rows(total, grad, data):
    """The render loss's energy residuals (3,) and their gradient rows (3, p) from the
    sums of :func:`_energy_sums` over every sample."""
    weight_sum = jnp.sum(data.weight)
    rho = energy_residuals(total, weight_sum, data)
    above = total > _energy_floor(data) * weight_sum  # below the floor: flat
    g = jnp.where(above[:, None],
                  jnp.sqrt(ENERGY_WEIGHT) * grad / jnp.maximum(total, 1e-30 * weight_sum)[:, None],
                  0.0)
    return rho, g


def sum_over_blocks(terms, data, n: int | None = None, part=None, parts: int = 1):
    """``terms(data)`` for a function that returns sums over the samples (any pytree
    of arrays), evaluated block by block when there are many samples: the sum of
    ``terms`` over consecutive blocks of :data:`BLOCK` samples or so. ``data`` is
    a pytree whose arrays all have the samples on their last axis (``n`` of them;
    a :class:`LossData`'s own count by default).

    With ``parts`` > 1 (static; it must divide the number of blocks, see
    :func:`block_count`), only the ``part``-th of ``parts`` equal runs of blocks is
    summed (``part`` may be traced): the runs can go on separate threads, and their
    sums add up to the whole."""
    n = data.weight.shape[-1] if n is None else n
    block = _block_size(n)
    if block_count(n) % parts:
        raise ValueError(f"{parts} parts do not divide the {block_count(n)} blocks of {n} samples")
    if block is None:
        return terms(data)
    per_part = n // block // parts
    first_block = 0 if part is None else part * per_part

    def block_at(i):  # arrays without the sample axis (an exposure) are shared
        return jax.tree_util.tree_map(
            lambda a: jax.lax.dynamic_slice_in_dim(a, i * block, block, axis=a.ndim - 1)
            if a.ndim and a.shape[-1] == n else a, data)

    def add_block(i, total):
        return jax.tree_util.tree_map(jnp.add, total, terms(block_at(i)))

    # from zeros, not from the first block's terms: those outside the loop were a
    # second copy of ``terms`` in every compiled program (a model's evaluation and
    # its derivatives), for one block's worth of work
    zeros = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype),
                                   jax.eval_shape(terms, block_at(first_block)))
    return jax.lax.fori_loop(first_block, first_block + per_part, add_block, zeros)


def block_count(n: int) -> int:
    """How many blocks :func:`sum_over_blocks` sums for ``n`` samples (1: one pass)."""
    block = _block_size(n)
    return 1 if block is None else n // block


def _block_size(n: int) -> int | None:
    """The divisor of ``n`` nearest :data:`BLOCK` (within a factor 2), when ``n`` is
    large enough for blocks to pay; else None."""
    if n < 4 * BLOCK:
        return None
    for d in range(BLOCK // 2):
        for size in (BLOCK - d, BLOCK + d):
            if n % size == 0:
                return size
    return None


def _normal_equations(u: Float[Array, " p"], model, data, meat: bool = False):
    """:func:`normal_equations` on one block of samples.

    A model ``f = kd/pi + sum_k scale_k * lobe_k`` (``model.lobe_scales``: one lobe
    for GGX or Phong, two for ggx2) has a Jacobian with structure worth using:
    the residual is linear in kd and the scales before the compression, so only
    the lobes' few shape parameters need forward-mode derivatives, and those on S
    samples rather than 3 S residuals (a lobe is shared by the channels). The
    colour columns follow in closed form, and the blocks of J^T J and J^T r are
    sums over the samples, without the (3 S, p) Jacobian: ~4x less work per step
    than ``jacfwd`` for one lobe, ~4x for two, and no (3 S, p) Jacobian in memory.
    Other models get :func:`_generic_normal_equations`. With ``meat``: the
    sandwich's meat, sum_i r_i^2 J_i^T J_i, too (:func:`normal_equations`); its
    terms share the Jacobian's, so it costs a few sums per step.
    """
    layout = _colour_layout(model)
    if layout is None:
        return _generic_normal_equations(u, (model, data), meat, energy=False)
    frame = data.frame
    n_lobes = len(layout.scale_specs)
    parts = _colour_parts(u, model, frame, layout)
    shape_u, f, slope, basis, shape_cols = (parts.shape_u, parts.f, parts.slope, parts.basis,
                                            parts.shape_cols)
    cos_i = jnp.maximum(frame.cos_i, 0.0)
    sqrt_w = jnp.sqrt(data.weight)
    x = exposed(f * cos_i, data.exposure)
    g, slope_x = compress_with_slope(x, data.loss, data.selector)
    r = sqrt_w * (g - data.target)  # (3, S)
    a = sqrt_w * exposed(cos_i * slope_x, data.exposure)  # dr/df, (3, S)
    a2, ar = a * a, a * r

    colour_at = layout.colour_at  # (3, K+1): u index of colour parameter m, channel c
    n = u.size

    def gram(w2):
        """sum_i w2_i J_i^T J_i over the residuals i = (c, s), J_i their gradient rows
        divided by a_i, for each row of ``w2`` (W, 3, S): J^T J for w2 = a^2. The
        weights go through the sums together: one pass over the Jacobian's columns
        for J^T J and the sandwich's meat."""
        # One batched product over the samples: per channel, the rows [basis,
        # d f / d shape] (q = K+1+J of them) weighted and multiplied by themselves.
        # Three-operand einsums here cost ~4x the model and its derivatives.
        k1 = basis.shape[0]
        jac_rows = jnp.concatenate([jnp.broadcast_to(basis, (3, *basis.shape)),
                                    jnp.moveaxis(shape_cols, 0, 1)], axis=1)  # (3, q, S)
        g = jnp.matmul(jac_rows[None] * w2[:, :, None, :],
                       jnp.swapaxes(jac_rows, -1, -2)[None])  # (W, 3, q, q)
        colour_colour = (g[:, :, :k1, :k1]
                         * slope.T[:, :, None] * slope.T[:, None, :])  # (W, 3, K+1, K+1)
        colour_shape = g[:, :, :k1, k1:] * slope.T[:, :, None]  # (W, 3, K+1, J)
        shape_shape = jnp.sum(g[:, :, k1:, k1:], axis=1)  # (W, J, J)
        # scatter the blocks to the model's parameter order (index arrays are static)
        rows = colour_at[:, :, None].repeat(n_lobes + 1, axis=2)
        cols = colour_at[:, None, :].repeat(n_lobes + 1, axis=1)
        out = jnp.zeros((w2.shape[0], n, n), u.dtype).at[:, rows, cols].set(colour_colour)
        cs_rows = colour_at[:, :, None].repeat(shape_u.size, axis=2)
        cs_cols = np.broadcast_to(layout.shape_at, cs_rows.shape)
        out = (out.at[:, cs_rows, cs_cols].set(colour_shape)
               .at[:, cs_cols, cs_rows].set(colour_shape))
        at = np.ix_(layout.shape_at, layout.shape_at)
        return out.at[:, at[0], at[1]].set(shape_shape)

    colour_r = jnp.sum(ar[:, None, :] * basis[None], axis=-1) * slope.T  # (3, K+1)
    shape_r = jnp.sum(ar[None] * shape_cols, axis=(1, 2))
    jtr = jnp.zeros(n, u.dtype).at[colour_at].set(colour_r).at[layout.shape_at].set(shape_r)
    if meat:
        jtj, meat_sum = gram(jnp.stack([a2, ar * ar]))
        return jnp.sum(r * r), jtj, jtr, meat_sum
    return jnp.sum(r * r), gram(a2[None])[0], jtr


class _ColourParts(NamedTuple):
    shape_u: Array  # (J,) the lobes' shape parameters, unconstrained
    f: Array  # (3, S) the model's values, clamped at 0
    slope: Array  # (K+1, 3): d f_c / d u of colour parameter m is slope[m, c] * basis[m]
    basis: Array  # (K+1, S): 1, then each unit lobe
    shape_cols: Array  # (J, 3, S): d f_c / d shape_j


def _colour_parts(u, model, frame, layout) -> _ColourParts:
    """What the closed-form Jacobian of a colour-linear model needs on ``frame``."""

    def lobes_of(shape_u):
        shape = {s.name: s.constrain(shape_u[j]) for j, s in enumerate(layout.shape_specs)}
        return model.unit_lobes(shape, frame)  # (K, S)

    shape_u = u[layout.shape_at]
    lobes = lobes_of(shape_u)
    d_lobes = jax.vmap(lambda t: jax.jvp(lobes_of, (shape_u,), (t,))[1])(
        jnp.eye(shape_u.size, dtype=u.dtype)
    )  # (J, K, S)

    def value_and_slope(spec, x):  # a colour parameter and d(value)/du, elementwise
        return jax.jvp(spec.constrain, (x,), (jnp.ones_like(x),))

    kd, dkd = value_and_slope(layout.kd_spec, u[layout.kd_at])
    scales, dscales = zip(*(value_and_slope(s, u[at])
                            for s, at in zip(layout.scale_specs, layout.scale_at)))
    scales = jnp.stack(scales)  # (K, 3)
    slope = jnp.concatenate([dkd[None] / jnp.pi, jnp.stack(dscales)])  # (K+1, 3)
    basis = jnp.concatenate([jnp.ones_like(lobes[:1]), lobes])  # (K+1, S)
    f = jnp.maximum(kd[:, None] / jnp.pi + jnp.einsum("kc,ks->cs", scales, lobes), 0.0)
    shape_cols = jnp.einsum("kc,jks->jcs", scales, d_lobes)  # (J, 3, S)
    return _ColourParts(shape_u, f, slope, basis, shape_cols)


def sandwich_terms(u: Float[Array, " p"], model, data):
    """(J^T J, sum_i r_i^2 J_i^T J_i) of :func:`residuals` at ``u``, in the
    unconstrained parameters: the bread and the meat of the sandwich covariance
    (``brdffit.fitting.uncertainty``), as :func:`normal_equations` sums them."""
    _, bread, _, meat = normal_equations(u, (model, data), meat=True)
    return bread, meat


class _ColourLayout(NamedTuple):
    """Where a colour-linear model's parameters sit in its unconstrained vector."""

    kd_at: np.ndarray  # (3,)
    kd_spec: ParamSpec  # KD, or its physical range (brdffit.fitting.physical)
    scale_specs: tuple[ParamSpec, ...]
    scale_at: tuple[np.ndarray, ...]  # (3,) each
    shape_specs: tuple[ParamSpec, ...]
    shape_at: np.ndarray  # (J,)
    colour_at: np.ndarray  # (3, K+1): kd, then each scale, per channel


def _colour_layout(model) -> _ColourLayout | None:
    """The layout of ``model``'s parameters if it is ``kd/pi + sum_k scale_k lobe_k``
    with every RGB parameter kd or a scale, else None."""
    if not model.lobe_scales:
        return None
    at, offset = {}, 0
    for s in model.param_specs:
        at[s.name] = np.arange(offset, offset + s.size)
        offset += s.size
    specs = {s.name: s for s in model.param_specs}
    rgb = {s.name for s in model.param_specs if s.rgb}
    if "kd" not in rgb or rgb != {"kd", *model.lobe_scales}:
        return None
    shape_specs = tuple(s for s in model.param_specs if not s.rgb)
    if not shape_specs:  # nothing to differentiate through the lobes: no gain
        return None
    colour = [at["kd"], *(at[k] for k in model.lobe_scales)]
    return _ColourLayout(
        kd_at=at["kd"], kd_spec=specs["kd"], scale_specs=tuple(specs[k] for k in model.lobe_scales),
        scale_at=tuple(at[k] for k in model.lobe_scales), shape_specs=shape_specs,
        shape_at=np.concatenate([at[s.name] for s in shape_specs]),
        colour_at=np.stack(colour, axis=1),
    )


def _generic_normal_equations(u, args, meat: bool = False, energy: bool = True):
    """From the Jacobian of the residuals (:func:`residual_jacobian`): of
    :func:`residuals` (the render loss's energy term included), or with
    ``energy=False`` of the per-sample ones only (one block of a sum,
    :func:`normal_equations` adds the energy term to the whole)."""
    r, jac = residual_jacobian(u, args, energy)
    out = (jnp.sum(r * r), jac.T @ jac, jac.T @ r)
    if meat:
        jr = jac * r[:, None]
        return out + (jr.T @ jr,)
    return out


def residual_jacobian(u, args, energy: bool = True):
    """The residuals (:func:`residuals`, or with ``energy=False`` the per-sample ones),
    flat (m,), and their Jacobian (m, p) at ``u`` (:func:`jacobian_of_params`)."""
    model, data = args
    of_params = residuals_of_params if energy else _sample_residuals_of_params
    return jacobian_of_params(lambda params: of_params(params, model, data).reshape(-1),
                              u, model)


def jacobian_of_params(fn, u, model):
    """``fn(params)`` (flat, (m,)) at ``params = model.constrain(u)``, and its Jacobian
    (m, p) in ``u``.

    ``jacfwd`` of the whole pushes all p tangents through the model at once: every
    intermediate carries p of them, though most depend on one or two parameters (a
    lobe's terms on its roughness alone). Where the parameters are their specs' own
    elementwise transforms of ``u`` (:meth:`AbstractBRDFModel.constrain`), this
    takes one forward-mode pass per parameter instead, the others held as constants,
    so that tangents go only through what depends on it (an RGB one's three at once),
    times its transform's slope. The same Jacobian to rounding (~1e-15 relative); a
    solver step's normal equations on 16384 samples cost 1.4x (rough_plastic) to 5.4x
    (standard_surface_coat) less: gltf_iridescence 107 -> 38 ms, standard_surface_sheen
    98 -> 29 ms (float64, medians of 11, one process)."""
    if type(model).constrain is not AbstractBRDFModel.constrain:
        jac, value = jax.jacfwd(lambda v: (fn(model.constrain(v)),) * 2, has_aux=True)(u)
        return value, jac
    params = model.constrain(u)

    def at(name):
        return lambda x: fn({**params, name: x})

    columns, i = [], 0
    for spec in model.param_specs:
        x, chunk = params[spec.name], u[i:i + spec.size]
        chunk = chunk if spec.rgb else chunk[0]
        _, slope = jax.jvp(spec.constrain, (chunk,), (jnp.ones_like(chunk),))
        if spec.rgb:
            d = jax.vmap(lambda t, f=at(spec.name), x=x: jax.jvp(f, (x,), (t,))[1])(
                jnp.eye(spec.size, dtype=x.dtype))
        else:
            d = jax.jvp(at(spec.name), (x,), (jnp.ones_like(x),))[1][None]
        columns.append(d * jnp.reshape(slope, (-1, 1)))
        i += spec.size
    return fn(params), jnp.concatenate(columns).T
