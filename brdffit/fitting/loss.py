"""The fitting losses and the error metrics, one definition for both.

Residual of bin b, channel c, for a loss with compression ``g``:

    r_cb = sqrt(w_b) * ( g(f_model_c(b) cos_i(b)) - g(f_meas_c(b) cos_i(b)) )

The loss is a choice (:data:`LOSSES`, docs/fitting.md says when to use which):

- ``"log"`` (default): ``g(x) = log(1 + x)``, after Löw et al. 2012 and Ngan et
  al. 2005, who fit in a log space so that the peak does not swamp the rest;
- ``"cube_root"``: ``g(x) = cbrt(x + 1e-6)``, the perceptual compression of
  Löw et al. 2012 and Sun et al. 2018 (closer to lightness than the log; the
  highlight counts more than under the log, less than in linear space). The
  offset keeps the slope finite at ``x = 0`` (``cbrt`` has an infinite one there);
  it cancels in every difference of values well above 1e-6 1/sr;
- ``"linear_cos"``: ``g(x) = x``, the linear radiance-like error under uniform
  lighting: the energy of the highlight decides, as in a rendered image without
  tone mapping.

with w_b the bin's solid-angle weight (see ``brdffit.io.grid``; times the scene
weight for scene-aware fits), normalised to sum 1 over the bins used. Only
measured, finite bins above the horizon have w_b > 0.

``log_rmse`` is the root of the weighted mean square of the bracket under the log
loss (``cube_root_rmse`` and ``rmse_cos`` the same under the other two):

    log_rmse = sqrt( sum_b w_b sum_c (...)^2 / (3 sum_b w_b) )

evaluated over **all** usable bins of the table (not just the fit's subsample).

Arrays are channel-major, (3, S), like the MERL file: XLA vectorises along the
long bin axis, which makes the loss ~3x cheaper than bin-major (S, 3) arrays.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from brdffit.models import AbstractBRDFModel
from brdffit.models.base import KD, KS, AbstractLobeModel
from brdffit.models.frame import Frame

#: The losses a fit can minimise; the first is the default.
LOSSES = ("log", "cube_root", "linear_cos")
DEFAULT_LOSS = "log"
#: The full-table metric that each loss is the (weighted) mean square of: every
#: result reports all three, whatever was optimised.
LOSS_METRIC = {"log": "log_rmse", "cube_root": "cube_root_rmse", "linear_cos": "rmse_cos"}
#: Offset inside the cube root (1/sr, times cos_i): finite slope at 0, far below
#: any measured value (``merl.MIN_PEAK`` is 1e-5 for the brightest bin).
CUBE_ROOT_OFFSET = 1e-6


def _cbrt(x):
    # exp(log(x)/3) for x > 0: XLA's CPU cbrt is ~20x slower over a full table, and
    # this agrees with it to 1e-6 relative in float32
    return jnp.exp(jnp.log(x) * (1.0 / 3.0))


def compress_values(x, loss: str):
    """``g(x)`` of the module docstring, for ``x = f cos_i >= 0``: the caller clamps
    (``compress`` does), so that the hot path holds no second clamp."""
    if loss == "log":
        return jnp.log1p(x)
    if loss == "cube_root":
        return _cbrt(x + CUBE_ROOT_OFFSET)
    if loss == "linear_cos":
        return x
    raise ValueError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")


def compress_slope(x, loss: str):
    """``g'(x)``, for the closed-form Jacobian of :func:`normal_equations` (``x >= 0``)."""
    if loss == "log":
        return 1.0 / (1.0 + x)
    if loss == "cube_root":
        c = _cbrt(x + CUBE_ROOT_OFFSET)
        return 1.0 / (3.0 * c * c)
    if loss == "linear_cos":
        return jnp.ones_like(x)
    raise ValueError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")


class LossData(eqx.Module):
    """One fixed-size batch of bins: geometry, compressed targets, weights, and the
    loss they are compressed for (static: each loss compiles its own fit)."""

    frame: Frame  # per-bin geometry, precomputed (see brdffit.models.frame), (S,)
    target: Float[Array, "3 s"]  # g(f_meas * cos_i) of the loss
    weight: Float[Array, " s"]  # sums to 1; 0 on padding and unusable bins
    loss: str = eqx.field(static=True, default=DEFAULT_LOSS)


def compress(
    f: Float[Array, "3 s"], cos_i: Float[Array, " s"], loss: str = DEFAULT_LOSS
) -> Float[Array, "3 s"]:
    """The compressed value g(f cos_i) that the loss compares."""
    return compress_values(jnp.maximum(f, 0.0) * jnp.maximum(cos_i, 0.0), loss)


def residuals(u: Float[Array, " p"], args) -> Float[Array, "3 s"]:
    model, data = args
    f = model.eval_channels(model.constrain(u), data.frame)
    return jnp.sqrt(data.weight) * (compress(f, data.frame.cos_i, data.loss) - data.target)


def sum_squares(u, model: AbstractBRDFModel, data: LossData):
    r = residuals(u, (model, data))
    return jnp.sum(r * r)


def error_metrics(u, model: AbstractBRDFModel, data: LossData) -> dict[str, Array]:
    """Every metric of parameters ``u`` on ``data`` (usually the full table), whatever
    loss ``data`` was made for.

    - ``log_rmse``, ``cube_root_rmse``: see the module docstring (``g`` of each loss).
    - ``rmse_cos``: the same weighting on (f_model - f_meas) cos_i, linear space (1/sr).
    - ``rel_peak_error``: relative error of the fitted value at the bin with the
      largest measured compressed value (how well the highlight is matched).
    """
    f = model.eval_channels(model.constrain(u), data.frame)
    fit_cos = jnp.maximum(f, 0.0) * jnp.maximum(data.frame.cos_i, 0.0)
    meas_cos = _uncompress(data.target, data.loss)

    def rmse(d):
        return jnp.sqrt(jnp.sum(data.weight * d * d) / 3.0)

    lin = fit_cos - meas_cos
    peak = jnp.argmax(jnp.where(data.weight > 0, jnp.sum(data.target, axis=0), -jnp.inf))
    rel_peak = jnp.max(jnp.abs(lin[:, peak]) / jnp.maximum(meas_cos[:, peak], 1e-12))
    return {
        "log_rmse": rmse(compress_values(fit_cos, "log") - compress_values(meas_cos, "log")),
        "cube_root_rmse": rmse(compress_values(fit_cos, "cube_root")
                               - compress_values(meas_cos, "cube_root")),
        "rmse_cos": rmse(lin),
        "rel_peak_error": rel_peak,
    }


def _uncompress(target, loss: str):
    if loss == "log":
        return jnp.expm1(target)
    if loss == "cube_root":
        return jnp.maximum(target**3 - CUBE_ROOT_OFFSET, 0.0)
    return target


def normal_equations(u: Float[Array, " p"], args):
    """(sum r^2, J^T J, J^T r) of :func:`residuals`, for the solver's step.

    For a ``kd/pi + ks * lobe`` model the Jacobian has structure worth using:
    the residual is linear in kd and ks before the compression, so only the
    lobe's few shape parameters need forward-mode derivatives, and those on S
    samples rather than 3 S residuals (the lobe is shared by the channels). The
    colour columns follow in closed form. That is ~4x less work per step than a
    plain ``jacfwd`` over all parameters, which is what other models get.
    """
    model, data = args
    if not _is_plain_lobe(model):
        return _generic_normal_equations(u, args)
    frame = data.frame
    n_shape = u.size - 6
    shape_specs = model.param_specs[2:]

    def lobe_of(shape_u):
        shape = {s.name: s.constrain(shape_u[j]) for j, s in enumerate(shape_specs)}
        return model.lobe(shape, frame)

    lobe = lobe_of(u[6:])
    d_lobe = jax.vmap(lambda t: jax.jvp(lobe_of, (u[6:],), (t,))[1])(
        jnp.eye(n_shape, dtype=u.dtype)
    )  # (n_shape, S)
    kd = KD.constrain(u[0:3])[:, None]
    ks = KS.constrain(u[3:6])[:, None]
    cos_i = jnp.maximum(frame.cos_i, 0.0)
    f = jnp.maximum(kd / jnp.pi + ks * lobe, 0.0)  # (3, S)
    sqrt_w = jnp.sqrt(data.weight)
    r = sqrt_w * (compress_values(f * cos_i, data.loss) - data.target)  # (3, S)
    a = sqrt_w * cos_i * compress_slope(f * cos_i, data.loss)  # dr/df, (3, S)
    dkd = jax.nn.sigmoid(u[0:3])[:, None] / jnp.pi  # d(kd/pi)/du, softplus' = sigmoid
    dks = jax.nn.sigmoid(u[3:6])[:, None]
    # Jacobian columns by channel c: kd_c -> a_c dkd_c, ks_c -> a_c lobe dks_c,
    # shape_j -> a_c ks_c dlobe_j. Blocks of J^T J and J^T r follow directly,
    # without materialising the (3 S, p) Jacobian.
    a_l = a * lobe
    ak = a * ks  # (3, S)
    g_kd = jnp.sum(a * r, axis=1) * dkd[:, 0]
    g_ks = jnp.sum(a_l * r, axis=1) * dks[:, 0]
    g_sh = jnp.einsum("cs,js->j", ak * r, d_lobe)
    kd_kd = jnp.sum(a * a, axis=1) * dkd[:, 0] ** 2
    kd_ks = jnp.sum(a * a_l, axis=1) * dkd[:, 0] * dks[:, 0]
    ks_ks = jnp.sum(a_l * a_l, axis=1) * dks[:, 0] ** 2
    kd_sh = jnp.einsum("cs,js->cj", a * ak, d_lobe) * dkd
    ks_sh = jnp.einsum("cs,js->cj", a_l * ak, d_lobe) * dks
    sh_sh = jnp.einsum("is,js->ij", d_lobe * jnp.sum(ak * ak, axis=0), d_lobe)
    jtj = jnp.block(
        [
            [jnp.diag(kd_kd), jnp.diag(kd_ks), kd_sh],
            [jnp.diag(kd_ks), jnp.diag(ks_ks), ks_sh],
            [kd_sh.T, ks_sh.T, sh_sh],
        ]
    )
    jtr = jnp.concatenate([g_kd, g_ks, g_sh])
    return jnp.sum(r * r), jtj, jtr


def _is_plain_lobe(model) -> bool:
    specs = model.param_specs
    return (
        isinstance(model, AbstractLobeModel)
        and len(specs) > 2
        and specs[:2] == (KD, KS)
        and all(not s.rgb for s in specs[2:])
    )


def _generic_normal_equations(u, args):
    jac, r = jax.jacfwd(lambda v: (residuals(v, args).reshape(-1),) * 2, has_aux=True)(u)
    return jnp.sum(r * r), jac.T @ jac, jac.T @ r
