"""The fitting loss and the error metrics, one definition for both.

Residual of bin b, channel c (``compressed`` space, after Löw et al. 2012 and
Ngan et al. 2005, who fit in a log space so that the peak does not swamp the
rest):

    r_cb = sqrt(w_b) * ( log(1 + f_model_c(b) cos_i(b)) - log(1 + f_meas_c(b) cos_i(b)) )

with w_b the bin's solid-angle weight (see ``brdffit.io.grid``; times the scene
weight for scene-aware fits), normalised to sum 1 over the bins used. Only
measured, finite bins above the horizon have w_b > 0.

``log_rmse`` is the root of the weighted mean square of the bracket:

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


class LossData(eqx.Module):
    """One fixed-size batch of bins: geometry, compressed targets, weights."""

    frame: Frame  # per-bin geometry, precomputed (see brdffit.models.frame), (S,)
    target: Float[Array, "3 s"]  # log1p(f_meas * cos_i)
    weight: Float[Array, " s"]  # sums to 1; 0 on padding and unusable bins


def compress(f: Float[Array, "3 s"], cos_i: Float[Array, " s"]) -> Float[Array, "3 s"]:
    """The compressed value log(1 + f cos_i) that the loss compares."""
    return jnp.log1p(jnp.maximum(f, 0.0) * jnp.maximum(cos_i, 0.0))


def residuals(u: Float[Array, " p"], args) -> Float[Array, "3 s"]:
    model, data = args
    f = model.eval_channels(model.constrain(u), data.frame)
    return jnp.sqrt(data.weight) * (compress(f, data.frame.cos_i) - data.target)


def sum_squares(u, model: AbstractBRDFModel, data: LossData):
    r = residuals(u, (model, data))
    return jnp.sum(r * r)


def error_metrics(u, model: AbstractBRDFModel, data: LossData) -> dict[str, Array]:
    """log_rmse and friends of parameters ``u`` on ``data`` (usually the full table).

    - ``log_rmse``: see the module docstring.
    - ``rmse_cos``: the same weighting on (f_model - f_meas) cos_i, linear space (1/sr).
    - ``rel_peak_error``: relative error of the fitted value at the bin with the
      largest measured compressed value (how well the highlight is matched).
    """
    f = model.eval_channels(model.constrain(u), data.frame)
    pred = compress(f, data.frame.cos_i)
    d = pred - data.target
    log_rmse = jnp.sqrt(jnp.sum(data.weight * d * d) / 3.0)
    meas_cos = jnp.expm1(data.target)
    lin = jnp.maximum(f, 0.0) * data.frame.cos_i - meas_cos
    rmse_cos = jnp.sqrt(jnp.sum(data.weight * lin * lin) / 3.0)
    peak = jnp.argmax(jnp.where(data.weight > 0, jnp.sum(data.target, axis=0), -jnp.inf))
    rel_peak = jnp.max(jnp.abs(lin[:, peak]) / jnp.maximum(meas_cos[:, peak], 1e-12))
    return {"log_rmse": log_rmse, "rmse_cos": rmse_cos, "rel_peak_error": rel_peak}


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
    r = sqrt_w * (jnp.log1p(f * cos_i) - data.target)  # (3, S)
    a = sqrt_w * cos_i / (1.0 + f * cos_i)  # dr/df, (3, S)
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
