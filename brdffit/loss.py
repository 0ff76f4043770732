"""The fitting loss and the error metrics, one definition for both.

Residual of bin b, channel c (``compressed`` space, after Löw et al. 2012 and
Ngan et al. 2005, who fit in a log space so that the peak does not swamp the
rest):

    r_bc = sqrt(w_b) * ( log(1 + f_model_c(b) cos_i(b)) - log(1 + f_meas_c(b) cos_i(b)) )

with w_b the bin's solid-angle weight (see ``brdffit.grid``; times the scene
weight for scene-aware fits), normalised to sum 1 over the bins used. Only
measured, finite bins above the horizon have w_b > 0.

``log_rmse`` is the root of the weighted mean square of the bracket:

    log_rmse = sqrt( sum_b w_b sum_c (...)^2 / (3 sum_b w_b) )

evaluated over **all** usable bins of the table (not just the fit's subsample).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .models import AbstractBRDFModel
from .models.frame import Frame


class LossData(eqx.Module):
    """One fixed-size batch of bins: directions, compressed targets, weights."""

    frame: Frame  # per-bin geometry, precomputed (see brdffit.models.frame)
    target: Float[Array, "s 3"]  # log1p(f_meas * cos_i)
    weight: Float[Array, " s"]  # sums to 1; 0 on padding


def compress(f, cos_i):
    """The compressed value log(1 + f cos_i) that the loss compares."""
    return jnp.log1p(jnp.maximum(f, 0.0) * cos_i[..., None])


def residuals(u: Float[Array, " p"], args) -> Float[Array, "s 3"]:
    model, data = args
    f = model.eval_frame(model.constrain(u), data.frame)
    return jnp.sqrt(data.weight)[:, None] * (compress(f, data.frame.cos_i) - data.target)


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
    f = model.eval_frame(model.constrain(u), data.frame)
    w = data.weight[:, None]
    pred = compress(f, data.frame.cos_i)
    d = pred - data.target
    log_rmse = jnp.sqrt(jnp.sum(w * d * d) / 3.0)
    meas = jnp.expm1(data.target)
    lin = jnp.expm1(pred) - meas
    rmse_cos = jnp.sqrt(jnp.sum(w * lin * lin) / 3.0)
    masked = jnp.where(w > 0, data.target, -jnp.inf)
    peak = jnp.argmax(jnp.sum(masked, axis=1))
    rel_peak = jnp.max(jnp.abs(lin[peak]) / jnp.maximum(meas[peak], 1e-12))
    return {"log_rmse": log_rmse, "rmse_cos": rmse_cos, "rel_peak_error": rel_peak}


def normal_equations(u: Float[Array, " p"], args):
    """(sum r^2, J^T J, J^T r) of :func:`residuals`, for the solver's step.

    For a ``kd/pi + ks * lobe`` model the Jacobian has structure worth using:
    the residual is linear in kd and ks before the compression, so only the
    lobe's few shape parameters need forward-mode derivatives, and those on S
    samples rather than 3 S residuals (the lobe is shared by the channels). The
    colour columns follow in closed form. That is ~5x less work per step than a
    plain ``jacfwd`` over all parameters, which is what other models get.
    """
    model, data = args
    if not _is_plain_lobe(model):
        return _generic_normal_equations(u, args)
    frame = data.frame
    n_shape = u.size - 6
    params = model.constrain(u)
    shape_specs = model.param_specs[2:]

    def lobe_of(shape_u):
        shape = {s.name: s.constrain(shape_u[j]) for j, s in enumerate(shape_specs)}
        return model.lobe(shape, frame)

    lobe = lobe_of(u[6:])
    d_lobe = jax.vmap(lambda t: jax.jvp(lobe_of, (u[6:],), (t,))[1], out_axes=1)(
        jnp.eye(n_shape, dtype=u.dtype)
    )  # (S, n_shape)
    kd, ks = params["kd"], params["ks"]
    cos_i = frame.cos_i[:, None]
    f = kd / jnp.pi + ks * lobe[:, None]
    f = jnp.maximum(f, 0.0)
    sqrt_w = jnp.sqrt(data.weight)[:, None]
    r = sqrt_w * (jnp.log1p(f * cos_i) - data.target)  # (S, 3)
    a = sqrt_w * cos_i / (1.0 + f * cos_i)  # dr/df, (S, 3)
    dkd = jax.nn.sigmoid(u[0:3])  # d softplus / du
    dks = jax.nn.sigmoid(u[3:6])
    eye = jnp.eye(3, dtype=u.dtype)
    j_kd = a[:, :, None] * (eye * dkd / jnp.pi)[None]
    j_ks = (a * lobe[:, None])[:, :, None] * (eye * dks)[None]
    j_shape = (a * ks)[:, :, None] * d_lobe[:, None, :]
    jac = jnp.concatenate([j_kd, j_ks, j_shape], axis=2).reshape(-1, u.size)
    r = r.reshape(-1)
    return jnp.sum(r * r), jac.T @ jac, jac.T @ r


def _is_plain_lobe(model) -> bool:
    from .models.base import KD, KS, AbstractLobeModel

    specs = model.param_specs
    return (
        isinstance(model, AbstractLobeModel)
        and specs[:2] == (KD, KS)
        and all(not s.rgb for s in specs[2:])
        and len(specs) > 2
    )


def _generic_normal_equations(u, args):
    jac, r = jax.jacfwd(lambda v: (residuals(v, args).reshape(-1),) * 2, has_aux=True)(u)
    return jnp.sum(r * r), jac.T @ jac, jac.T @ r
