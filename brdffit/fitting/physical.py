"""A physically bounded fit: ``fit(table, model, physical=True)``.

The fit of ``model`` under the two constraints a renderer's material must meet:

1. **ranges**: every reflectance at most 1, the model's ``physical_specs``
   (``kd`` and the lobe scales ``ks``...; ``brdffit.models.base``); ranges already
   within [0, 1] (``f0``, glTF's factors) are kept;
2. **energy**: the directional albedo ``a_c(theta_i) = int f_c cos_o dw_o <= 1`` at
   every incidence and in every channel (``brdffit.models.albedo``).

How it is solved:

- the unconstrained fit comes first (``physical=False``, the same options). Where it
  already meets both constraints (the exact check of ``brdffit.models.albedo``) it
  is the bounded optimum too, and is returned as it is, with its report;
- otherwise the model with its physical ranges (``kd`` and the scales on a sigmoid
  bounded at 1, :class:`PhysicalRanges`) is solved again by the fit's own least
  squares, from the unconstrained optimum moved into the feasible set (clipped to
  the ranges, its reflectances scaled until the albedo is below the limit), with one
  barrier term per incidence and channel added to the data's sum of squares:

      mu b(s),   b(s) = -log(1 - s) - s,   s = a_c(theta_i) / (1 - MARGIN)

  ``b`` is ~ s^2 / 2 far from the limit (a negligible pull) and infinite at it, so
  every step the solver accepts stays feasible; its gradient and curvature enter the
  solver's normal equations exactly in ``s`` (:func:`_normal_equations`). ``mu`` is
  each of BARRIERS in turn times the data loss at the start, so the pull is the same
  on a dim table and a bright one. ``a_c`` is a coarse quadrature
  (:func:`coarse_albedo`: the incidences of ``brdffit.models.albedo`` and 1,792 half
  vectors; for lobes from alpha = 1e-3 to 2 within 0.2% of the exact albedo where it
  is largest, 1% at any incidence), cheap enough for every step;
- a final exact check with ``brdffit.models.albedo`` (512 x 256 half vectors per
  incidence): where the albedo still passes 1, the linear reflectance parameters
  (``kd``, the lobe scales, ``base_color``) are scaled by one factor below 1 until it
  does not, reported as a clamp.

The result is the model's own (same name and parameters; a physical fit exports
like any other) with ``FitResult.physical``: the unconstrained and the bounded
``log_rmse``, the relative cost, the largest albedo before and after, the active
constraints and the scale (docs/results.md).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdffit import runtime
from brdffit.fitting import problem
from brdffit.fitting import solver as solvers
from brdffit.fitting.assemble import Later, assemble
from brdffit.fitting.inputs import TableInput
from brdffit.fitting.loss import (
    DEFAULT_LOSS,
    sum_squares,
)
from brdffit.fitting.options import (
    DEFAULT_MAX_STEPS,
    DEFAULT_PRECISION,
    DEFAULT_SEED,
    DEFAULT_SOLVER,
)
from brdffit.fitting.problem import plain_params
from brdffit.fitting.result import FitResult
from brdffit.fitting.sampling import DEFAULT_SAMPLES
from brdffit.fitting.solve import Solve
from brdffit.fitting.uncertainty import parameter_uncertainty
from brdffit.models.base import AbstractBRDFModel, Params, ParamSpec
from brdffit.models.frame import Frame, shading_frame

#: The barrier's weights, relative to the data loss at the start, solved in turn
#: (the second from the first's optimum: a small weight alone takes longer): the
#: last holds a binding albedo ~1e-4 below its limit and moves a free one by
#: nothing measurable.
BARRIERS = (1e-2, 1e-4)
#: The coarse albedo is held below 1 - MARGIN: the coarse quadrature's error where
#: the albedo is largest (tests/test_physical.py), so that the exact check rarely
#: needs the scale.
MARGIN = 0.002
#: The starts are scaled to a coarse albedo at most this fraction of the limit:
#: strictly inside, where the barrier is finite.
START_LIMIT = 0.99
#: Half-vector grid of the coarse quadrature (:func:`theta_h_nodes`): theta_h from
#: THETA_H_MIN to pi/2, log-spaced by STEP_X below ~SCALE_H, even steps of
#: SCALE_H * STEP_X above; N_PHI_H cells of phi_h on [0, pi] (the albedo of an
#: isotropic BRDF is symmetric about the plane of incidence).
THETA_H_MIN, SCALE_H, STEP_X, N_PHI_H = 1e-6, 0.15, 0.2, 16
#: An albedo within this of 1 counts as a binding energy constraint in the report.
BINDING = 5e-3
#: Parameters scaled by the final clamp: those the BRDF is linear (or, for glTF's
#: base colour, monotonic) in.
LINEAR_REFLECTANCES = ("kd", "ks", "ks1", "ks2", "base_color")


class PhysicalRanges(AbstractBRDFModel):
    """``base`` with its physical ranges (:attr:`AbstractBRDFModel.physical_specs`): the
    same BRDF and parameter names, reflectances bounded at 1 in the fit."""

    base: AbstractBRDFModel

    @property
    def name(self) -> str:
        return self.base.name

    @property
    def param_specs(self) -> tuple[ParamSpec, ...]:
        return self.base.physical_specs

    @property
    def physical_specs(self) -> tuple[ParamSpec, ...]:
        return self.base.physical_specs

    @property
    def lobe_scales(self) -> tuple[str, ...]:
        return self.base.lobe_scales

    def unit_lobes(self, shape: Params, frame: Frame):
        return self.base.unit_lobes(shape, frame)

    def eval_frame(self, params: Params, frame: Frame):
        return self.base.eval_frame(params, frame)

    def eval_channels(self, params: Params, frame: Frame):
        return self.base.eval_channels(params, frame)

    def compiled_form(self) -> PhysicalRanges:
        return dataclasses.replace(self, base=self.base.compiled_form())


# -- the coarse albedo ------------------------------------------------------------------


class AlbedoGrid(eqx.Module):
    """Direction pairs and weights of :func:`coarse_albedo`: for each incidence of
    ``brdffit.models.albedo.THETA_I_DEG``, wo = the mirror of wi about each half
    vector h, weight cos_o * 4 (wi.h) dw_h (0 where wo is below the horizon)."""

    frame: Frame  # (n_incidences * n_h,)
    weight: jax.Array  # (n_incidences, n_h)


def theta_h_nodes() -> tuple[np.ndarray, np.ndarray]:
    """Nodes in theta_h and their weights for ``int F(theta) sin(theta) dtheta``:
    the midpoint rule in ``x`` on ``theta = SCALE_H softplus(x)``, which is
    log-spaced for small angles (a lobe of any width is a smooth bump in
    ``log theta``, covered by the same number of nodes) and evenly spaced, by
    ``SCALE_H STEP_X``, for large ones (the wide lobes, and the horizon's cut)."""
    x_lo = math.log(math.expm1(THETA_H_MIN / SCALE_H))
    x_hi = (np.pi / 2) / SCALE_H + math.log(-math.expm1(-(np.pi / 2) / SCALE_H))
    n = math.ceil((x_hi - x_lo) / STEP_X)
    step = (x_hi - x_lo) / n
    x = x_lo + (np.arange(n) + 0.5) * step
    theta = SCALE_H * np.logaddexp(0.0, x)
    slope = SCALE_H / (1.0 + np.exp(-x))  # dtheta/dx
    return theta, np.sin(theta) * slope * step


@functools.cache
@runtime.in_float64
def albedo_grid(dtype_name: str = "float64") -> AlbedoGrid:
    from brdffit.models.albedo import mirrored_directions

    theta, band = theta_h_nodes()
    phi = (np.arange(N_PHI_H) + 0.5) / N_PHI_H * np.pi
    tt, pp = np.meshgrid(theta, phi, indexing="ij")
    h = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], -1).reshape(-1, 3)
    dw_h = np.repeat(band, N_PHI_H) * (2 * np.pi / N_PHI_H)  # both halves of phi_h
    wi, wo, weight = mirrored_directions(h, dw_h)
    frame = shading_frame(jnp.asarray(wi.reshape(-1, 3), dtype_name),
                          jnp.asarray(wo.reshape(-1, 3), dtype_name))
    return AlbedoGrid(frame=frame, weight=jnp.asarray(weight, dtype_name))


def coarse_albedo(model: AbstractBRDFModel, params: Params, grid: AlbedoGrid):
    """Directional albedo (3, n_incidences) of ``model`` on the coarse grid."""
    f = model.eval_channels(params, grid.frame)
    return jnp.einsum("cin,in->ci", f.reshape(3, *grid.weight.shape), grid.weight)


# -- the bounded solve -------------------------------------------------------------------


@eqx.filter_jit
def _coarse_albedo_of(model, u, grid):
    return coarse_albedo(model, model.constrain(u), grid)


def _albedo_ratio(u, model, grid):
    """s of the module docstring: each coarse albedo over its limit, (3 n_incidences,)."""
    return coarse_albedo(model, model.constrain(u), grid).reshape(-1) / (1.0 - MARGIN)


def _barrier(u, model, grid, mu):
    """The barrier residuals ``sqrt(mu b(s))`` (3 * n_incidences); inf outside. What the
    solvers without :func:`_normal_equations` (dogleg, bfgs) minimise."""
    s = _albedo_ratio(u, model, grid)
    inside = s < 1.0
    t = jnp.where(inside, s, 0.5)
    # b(s) / s^2, from its series near 0 (the closed form cancels there): then r is
    # s sqrt(mu b / s^2), smooth through s = 0 (a black channel), never sqrt(0)'s slope
    small = t < 1e-2
    ts = jnp.where(small, 0.5, t)
    ratio = jnp.where(small, 0.5 + t / 3.0 + t * t / 4.0 + t**3 / 5.0,
                      (-jnp.log1p(-ts) - ts) / (ts * ts))
    return jnp.where(inside, t * jnp.sqrt(mu * ratio), jnp.inf)


class AlbedoBarrier(eqx.Module):
    """The energy bound as a term of the fit's objective
    (``brdffit.fitting.problem.ObjectiveTerm``): ``mu sum_k b(s_k)`` over the coarse
    albedo's incidences and channels. The fit's own solve (``problem.solve_batch``)
    adds it to the data's sum of squares: its residuals for the solvers that read
    residuals, its normal equations for those that read them."""

    grid: AlbedoGrid
    mu: jax.Array

    def residuals(self, u, model):
        return _barrier(u, model, self.grid, self.mu)

    def normal_equations(self, u, model):
        """The barrier's share of the normal equations, in the generalised Gauss-Newton
        form: for ``sum_k mu b(s_k)``, gradient ``mu b'(s_k) grad s_k`` and curvature
        ``mu b''(s_k) grad s_k grad s_k^T``, exact in ``s``. (The plain Gauss-Newton of
        ``sqrt(mu b)`` underestimates that curvature by a factor ~2 log(1/(1 - s)) near
        the limit: its steps overshoot there, are refused, and the fit crawls.)"""
        ds, s = jax.jacfwd(lambda v: (_albedo_ratio(v, model, self.grid),) * 2,
                           has_aux=True)(u)
        inside = s < 1.0
        t = jnp.where(inside, s, 0.5)
        b = jnp.where(inside, -jnp.log1p(-t) - t, jnp.inf)  # outside: refused by the solver
        slope = t / (1.0 - t)  # b'
        curvature = 1.0 / ((1.0 - t) * (1.0 - t))  # b''
        # sum r^2 = loss, J^T r = gradient / 2, J^T J = curvature / 2 (the solver's
        # convention)
        return (self.mu * jnp.sum(b), 0.5 * self.mu * (ds.T * curvature) @ ds,
                0.5 * self.mu * ds.T @ slope)


# -- ranges, the exact check and the clamp ----------------------------------------------


def clip_to_ranges(model: AbstractBRDFModel, params: dict) -> tuple[dict, list[str]]:
    """``params`` clipped into ``model.physical_specs``, and one line per value that
    was outside (``"range: kd[R] <= 1"``)."""
    out, clipped = {}, []
    for spec in model.physical_specs:
        v = np.asarray(params[spec.name], float)
        hi = np.inf if spec.upper is None else spec.upper
        for c, x in zip("RGB" if v.ndim else " ", np.atleast_1d(v), strict=True):
            if x > hi:
                label = spec.name + (f"[{c}]" if v.ndim else "")
                clipped.append(f"range: {label} <= {hi:g}")
        out[spec.name] = np.clip(v, spec.lower, hi)
    return plain_params(out), clipped


def _albedo(model: AbstractBRDFModel, params: dict) -> np.ndarray:
    from brdffit.models.albedo import directional_albedo

    return directional_albedo(model, params)


def _scaled(model: AbstractBRDFModel, params: dict, s: float) -> dict:
    linear = {spec.name for spec in model.param_specs} & set(LINEAR_REFLECTANCES)
    return {k: (np.asarray(v) * s).tolist() if k in linear else v for k, v in params.items()}


def scale_to_limit(model: AbstractBRDFModel, params: dict, albedo_of, limit: float,
                   albedo: np.ndarray | None = None) -> tuple[dict, float, np.ndarray]:
    """``params`` with the linear reflectances scaled by the largest factor ``s <= 1``
    that keeps ``albedo_of(params)`` (any shape) at most ``limit``; returns
    ``(params, s, albedo)``. The BRDF is linear in them for every lobe model (one
    step), quadratic in glTF's base colour (a few steps)."""
    a = albedo_of(params) if albedo is None else albedo
    s = 1.0
    for _ in range(12):
        if a.max() <= limit:
            return (params if s == 1.0 else _scaled(model, params, s)), s, a
        s *= limit * (1.0 - 1e-9) / float(a.max())
        a = albedo_of(_scaled(model, params, s))
    lo, hi = 0.0, s  # reached by no model here; bisection keeps the promise
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if albedo_of(_scaled(model, params, mid)).max() <= limit:
            lo = mid
        else:
            hi = mid
    return _scaled(model, params, lo), lo, albedo_of(_scaled(model, params, lo))


def energy_clamp(model: AbstractBRDFModel, params: dict,
                 albedo: np.ndarray | None = None) -> tuple[dict, float, np.ndarray]:
    """:func:`scale_to_limit` under the exact albedo (``brdffit.models.albedo``) and 1."""
    return scale_to_limit(model, params, lambda p: _albedo(model, p), 1.0, albedo)


def _argmax(albedo: np.ndarray) -> tuple[list[float], float]:
    from brdffit.models.albedo import THETA_I_DEG

    i = int(np.argmax(albedo.max(axis=1)))
    return albedo[i].tolist(), float(THETA_I_DEG[i])


def _binding(albedo: np.ndarray) -> list[str]:
    """One line per channel whose albedo is at its limit 1 (within BINDING)."""
    from brdffit.models.albedo import THETA_I_DEG

    out = []
    for c, name in enumerate("RGB"):
        i = int(np.argmax(albedo[:, c]))
        if albedo[i, c] >= 1.0 - BINDING:
            out.append(f"energy: albedo[{name}] <= 1 (largest {albedo[i, c]:.4f} at "
                       f"{THETA_I_DEG[i]:g} deg)")
    return out


def _at_upper(model: AbstractBRDFModel, params: dict) -> list[str]:
    """One line per reflectance held at its physical upper bound 1."""
    out = []
    own = {s.name: s for s in model.param_specs}
    for spec in model.physical_specs:
        if spec.upper is None or own[spec.name].upper == spec.upper:
            continue  # not a range the physical fit added
        v = np.atleast_1d(np.asarray(params[spec.name], float))
        for c, x in zip("RGB" if spec.rgb else " ", v, strict=True):
            if x >= spec.upper * (1 - 1e-4):
                out.append(f"range: {spec.name}{f'[{c}]' if spec.rgb else ''} <= {spec.upper:g}")
    return out


def report(free: FitResult, bounded_error: dict, before: np.ndarray, after: np.ndarray,
           active: list[str], scale: float) -> dict:
    """``FitResult.physical`` (docs/results.md): plain, finite numbers."""
    free_e = free.error.get("log_rmse")
    bounded_e = bounded_error.get("log_rmse")
    cost = (bounded_e / free_e - 1.0 if free_e and bounded_e is not None
            and math.isfinite(free_e) and math.isfinite(bounded_e) else None)
    a_before, at_before = _argmax(before)
    a_after, at_after = _argmax(after)
    return {
        "unconstrained_log_rmse": free_e,
        "log_rmse": bounded_e,
        "relative_cost": cost,
        "albedo_max_before": a_before,
        "albedo_max_before_theta_deg": at_before,
        "albedo_max_after": a_after,
        "albedo_max_after_theta_deg": at_after,
        "active": active,
        "scale": scale,
        "unconstrained_params": free.params,
        "unconstrained_result": free.result,
    }


# -- the bounded step over a free fit -------------------------------------------------


@runtime.in_float64
def bound(table, free: FitResult, *, model: AbstractBRDFModel | None = None,
          loss: str = DEFAULT_LOSS, solver: str = DEFAULT_SOLVER,
          samples: int | None = DEFAULT_SAMPLES, precision: str = DEFAULT_PRECISION,
          max_steps: int = DEFAULT_MAX_STEPS, seed: int = DEFAULT_SEED,
          bin_weight=None) -> FitResult:
    """The physically bounded fit from ``free``, an unconstrained fit of ``table`` made
    with these options (those of ``fit``, ``samples=None`` for every bin): what
    ``fit(..., physical=True)`` returns, without fitting ``free`` again (the benchmark
    reports both). ``model``: the model instance, where ``free.model`` is not a
    registry name."""
    from brdffit import models

    t0 = time.perf_counter()
    model = models.get(free.model) if model is None else model
    if bin_weight is not None:
        bin_weight = np.asarray(bin_weight, dtype=np.float64).ravel()
    clipped, outside = clip_to_ranges(model, free.params)
    before = _albedo(model, free.params)
    if not outside and before.max() <= 1.0:  # the unconstrained optimum is feasible
        return dataclasses.replace(
            free, time_s=free.time_s + time.perf_counter() - t0,
            physical=report(free, free.error, before, before,
                            _at_upper(model, free.params) + _binding(before), 1.0))

    bounded = PhysicalRanges(model)
    dtype = problem.DTYPES[precision]
    prep = problem.prepare(table, bin_weight, samples, seed, precision, loss)
    grid = albedo_grid(jnp.dtype(dtype).name)

    def coarse(p):
        u = jnp.asarray(bounded.unconstrain(p), dtype)
        return np.asarray(_coarse_albedo_of(bounded, u, grid))

    # strictly inside the coarse limit, where the barrier is finite
    start, _, _ = scale_to_limit(model, clipped, coarse, START_LIMIT * (1.0 - MARGIN))
    u_start = bounded.unconstrain(start)
    # the barrier's scale: the data loss of the start, the bounded problem's own (the
    # unconstrained fit's can be ~0, on a table the model made)
    start_loss = float(sum_squares(jnp.asarray(u_start, dtype), bounded, prep.data))
    u, result, n_steps = u_start, "nonfinite", 0
    for weight in BARRIERS:  # each solve starts from the previous one's optimum
        mu = jnp.asarray(weight * max(start_loss, 1e-30), dtype)
        solve = Solve(bounded, solver, precision, prep.data, max_steps,
                      term=AlbedoBarrier(grid, mu))
        out = solve(np.asarray(u)[None])
        if not (np.all(np.isfinite(out.values[0])) and np.isfinite(out.losses[0])):
            break  # diverged: keep the last finite point (at worst the start)
        u, result = out.values[0].astype(np.float64), solvers.STATUS_NAMES[int(out.codes[0])]
        n_steps += int(out.steps[0])
    params = plain_params(problem.constrained(bounded, np.asarray(u)))
    params, scale, after = energy_clamp(model, params)
    if scale < 1.0:
        u = bounded.unconstrain(params)
    active = outside + [a for a in _at_upper(model, params) if a not in outside]
    active += _binding(after)
    if scale < 1.0:
        names = sorted({s.name for s in model.param_specs} & set(LINEAR_REFLECTANCES))
        active.append(f"clamp: {', '.join(names)} scaled by {scale:.6g} (exact energy check)")
    bounded_fit = assemble(
        TableInput(table), model, model.unconstrain(params), params, prep, result=result,
        steps=n_steps, starts=1,
        # the data's own loss on the solver's samples, without the barrier
        sample_loss=float(sum_squares(jnp.asarray(u, dtype), bounded, prep.data)),
        loss=loss, solver=solver, precision=precision, t0=t0,
        uncertainty=Later(lambda: parameter_uncertainty(bounded, u, prep.data)),
        physical=bool(active), notes=(*free.notes, "the bounded step started from the "
                                     "free fit's optimum, one start",
                                     # a limit per solve: 331 steps under --max-steps 256
                                     # read as a limit broken
                                     f"steps counts the bounded step's {len(BARRIERS)} "
                                     f"barrier solves, each of at most {max_steps}; the "
                                     "result is the last one's"))
    return dataclasses.replace(
        bounded_fit, time_s=free.time_s + time.perf_counter() - t0,
        physical=report(free, bounded_fit.error, before, after, active, scale))

