"""Levenberg-Marquardt on the fused normal equations, and the optimality test that
decides whether a fit converged.

Why our own solver: optimistix's ``LevenbergMarquardt`` keeps the Jacobian as a
lazy linear operator and solves the damped problem by QR of the stacked
``[J; sqrt(lambda) I]``: robust, but on a BRDF fit (~10^5 residuals, <= 16
parameters) each step costs ~15x one forward-mode Jacobian. Here each trial
point costs one ``jacfwd`` (all parameter tangents in one vectorised pass),
then ``J^T J`` (p x p) and ``J^T r``, and the damped step is a p x p solve.
For p this small the normal equations lose nothing that matters: the fit's
parameters are well scaled by their transforms, and the damping keeps the
system positive definite.

It plugs into ``optimistix.least_squares`` like any solver: ``throw=False``
results, ``num_steps`` stats.

**When to stop.** A fit stops on evidence of an optimum, never on a run of small
steps: the Gauss-Newton decrement

    dec = (J^T r)^T (J^T J)^+ (J^T r)

is the reduction of ``sum r^2`` that the local linear model of the residuals
still promises; the fit is optimal when ``dec <= gtol * sum r^2``, a test
relative to the problem's own scale and invariant to how the parameters are
scaled. Parameters at a bound are the exception (a Karush-Kuhn-Tucker test): a
fit's parameters live on unconstrained transforms (softplus, sigmoid) that only
approach a bound along a flat tail, where the decrement would keep promising
the reduction that crossing the bound would bring. A coordinate in such a tail
(``bound_side``) whose descent and Gauss-Newton step point further out is
*pinned*: held while the free coordinates take the damped step around it, then,
once they have settled, moved outward by one full step per iteration (its value
shrinks towards the bound geometrically); the test counts the free decrement
plus what the pinned ones would still gain on the way to their bound. Without this, one colour
channel of ``ks`` heading for 0 dominated every capped step and the rest of the
fit crawled (issue 10: ggx2 on pink-felt stopped at 1.6x its optimum).

Other stops say what they are: the step limit (``max_steps``), and *stalled*
(the loss no longer moves, or no representable step improves it) while the
test does not hold.

Damping follows Nielsen (1999): lambda *= max(1/3, 1 - (2 rho - 1)^3) on an
accepted step, lambda *= nu, nu *= 2 on a rejected one; Marquardt's scaling
by diag(J^T J) makes the damping invariant to parameter scale.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Bool, Float, Int

from brdffit.fitting.result import STATUS_NAMES  # noqa: F401 - re-exported
from brdffit.models.base import HELD

#: Damping beyond which no step can change the parameters at float precision.
_LAMBDA_MAX = 1e14
#: Longest step, in the unconstrained parameters (max norm), that a solve takes.
MAX_STEP = 2.0
#: ... except for a scale on a softplus well above its knee, which may change by this
#: fraction of itself in one step: there the softplus is the identity, and a fixed cap
#: of 2 took a ks of 5,500 wanting 8,000 (a table in other units: kd and ks in the
#: thousands, still within the reader's range) over 1,000 steps. Below u = 4 the cap
#: is MAX_STEP's, as before: no fit of values in MERL's range takes another path.
RELATIVE_STEP = 0.5
#: Relative diagonal of J^T J below which a direction counts as unidentified in
#: the optimality test: a column norm of 1e-10 of the largest (lstsq's rcond).
_RANK_FLOOR = 1e-20

#: Why a solve stopped (``_LMState.stop``).
RUNNING, OPTIMAL, STALLED, STUCK = 0, 1, 2, 3

#: Indices into ``STATUS_NAMES`` (the result schema's names).
SUCCESSFUL, MAX_STEPS, STATUS_STALLED, NONFINITE = range(4)


def gtol_for(dtype) -> float:
    """Relative decrement below which a fit is optimal. float64 resolves the
    residuals' projection to ~1e-8 of the loss; float32 to ~1e-4."""
    return 1e-7 if jnp.dtype(dtype) == jnp.float64 else 1e-4


def exact_fit_floor(dtype) -> float:
    """A loss below this fraction of the data's own scale (the loss of a zero
    model) is an exact fit: rounding, not the model, makes the residuals, and
    the decrement test is meaningless there. Relative, so a dim table (every
    value x 1e-6) is judged like a bright one."""
    return 1e-20 if jnp.dtype(dtype) == jnp.float64 else 1e-10


#: The smallest data scale, per unit weight, that :func:`loss_floor` measures from.
#: A table whose sampled values are all 0 (one hot bin elsewhere, say) has scale 0:
#: every model is then worse than "exact", and a reflectance sliding to 0 through
#: exp(u) took every allowed step (an auto fit of such a table ran 84 s). A model
#: ~1e-25 fits zeros exactly for any purpose; measured data sits far above this
#: (a MERL table scaled by 1e-6 still has ~1e-16 per unit weight).
ZERO_SCALE = 1e-30


def loss_floor(target, weight):
    """The loss of an exact fit on these data: :func:`exact_fit_floor` of their own
    scale (the loss of a zero model), that scale never taken below
    :data:`ZERO_SCALE` per unit weight."""
    scale = jnp.maximum(jnp.sum(weight * target**2), ZERO_SCALE * jnp.sum(weight))
    return exact_fit_floor(target.dtype) * scale


def _residual_and_normal(fn, y, args, options):
    """sum r^2, J^T J, J^T r and the meat at y (None where not asked for).

    ``options["normal_equations"]``, when given, computes them from (y, args)
    exploiting the problem's structure, the meat too where it returns four terms
    (``brdffit.fitting.loss.normal_equations_with_meat``); otherwise one
    forward-mode pass, without the meat.
    """
    if options and "normal_equations" in options:
        out = options["normal_equations"](y, args)
        return (*out, None) if len(out) == 3 else out
    flat, unravel = ravel_pytree(y)

    def flat_fn(v):
        out, _ = fn(unravel(v), args)
        r, _ = ravel_pytree(out)
        return r, r

    jac, r = jax.jacfwd(flat_fn, has_aux=True)(flat)
    return jnp.sum(r * r), jac.T @ jac, jac.T @ r, None


def _solve_spd(a: Float[Array, "p p"], b: Float[Array, " p"]) -> Float[Array, " p"]:
    """Gauss-Jordan elimination without pivoting, for the damped normal equations.

    The system is symmetric positive definite (J^T J plus a positive diagonal), for
    which elimination without pivoting is as stable as Cholesky. Written in plain
    ``jnp`` because ``jnp.linalg.solve`` lowers to a LAPACK call whose lowering
    alone costs ~0.5 s in every new process, for a p x p system with p <= ~20.
    """
    n = a.shape[0]
    m = jnp.concatenate([a, b[:, None]], axis=1)

    def eliminate(k, m):
        pivot = m[k, k]
        row = m[k] / jnp.where(jnp.abs(pivot) > 1e-300, pivot, 1e-300)
        factors = m[:, k].at[k].set(0.0)
        return (m - factors[:, None] * row[None, :]).at[k].set(row)

    return jax.lax.fori_loop(0, n, eliminate, m)[:, n]


def _in_tail(bound_side: Int[Array, " p"]) -> Bool[Array, " p"]:
    """Coordinates in a flat tail of their transform (``bound_side`` -1 / +1), as
    against free (0) or a held layer's shape (``HELD + i``), which is at no bound."""
    return jnp.abs(bound_side) == 1


def pinned_coordinates(jtj, jtr, bound_side: Int[Array, " p"]) -> Bool[Array, " p"]:
    """Coordinates held at a bound: in a flat tail (``bound_side`` = -1 / +1), with
    both the steepest descent ``-J^T r`` and the Gauss-Newton step pointing further
    out, the latter by more than one capped step (``MAX_STEP``): the optimum lies
    beyond the bound, as when a bound constraint is active.

    The step-length condition is what makes this scale-free: a dim table's kd of
    1e-7 sits in the softplus tail too, but its optimum is a step or two away, so
    it stays free.

    A tail coordinate whose column is numerically unidentified (``_RANK_FLOOR``)
    and whose descent points outward is pinned too, whatever its step: its damped
    step is then ~1e10 and meaningless, yet its share of the decrement kept a fit
    from ever passing the optimality test (a lobe's colour channel at ks ~ 1e-15)."""
    full = _damped_step(jtj, jtr, jnp.finfo(jtj.dtype).eps ** 0.5, jnp.zeros_like(bound_side, bool))
    d = jnp.diag(jtj)
    unidentified = d <= _RANK_FLOOR * jnp.max(d)
    outward = (-jtr * bound_side >= 0) & ((full * bound_side >= MAX_STEP) | unidentified)
    pinned = _in_tail(bound_side) & outward
    # HELD + i: a shape of a layer whose weight (coordinate i) sits in its lower tail
    # (a model's solver_bound_side); held still where that weight is pinned
    shape = bound_side >= HELD
    return pinned | (shape & pinned[jnp.where(shape, bound_side - HELD, 0)])


def _damped_step(jtj, jtr, lam, pinned, outward=None, floor=1e-12):
    """The LM step with Marquardt scaling on the free coordinates, given the move
    ``outward`` (0 where not pinned) of the pinned ones. ``floor`` (relative to the
    largest diagonal) keeps a vanishing column's damping from vanishing too; a
    floor-free scaling let near-zero lobes take wild steps (measured: worse fits
    of ggx2 on real materials)."""
    outward = jnp.zeros_like(jtr) if outward is None else outward
    d = jnp.diag(jtj)
    diag = jnp.maximum(d, floor * jnp.max(d) + jnp.finfo(d.dtype).tiny)
    free = ~pinned
    system = jnp.where(free[:, None] & free[None, :], jtj + lam * jnp.diag(diag), 0.0)
    system = system + jnp.diag(jnp.where(free, 0.0, 1.0))
    rhs = jnp.where(free, -(jtr + jtj @ outward), 0.0)
    delta = jnp.where(free, _solve_spd(system, rhs), outward)
    return jnp.where(jnp.all(jnp.isfinite(delta)), delta, 0.0)


def split_decrement(jtj, jtr, bound_side):
    """(pinned, free decrement, pinned gain): the Gauss-Newton decrement over the
    free coordinates, and what the pinned ones would still give on their way to
    the bound. In a flat tail a parameter's distance to its bound is its
    transform's slope (softplus ~ exp(u), sigmoid ~ exp(-|u|)), so that gain is
    ~ |d(sum r^2)/du| = 2 |J^T r| per pinned coordinate.

    The damping here only regularises unidentified directions (Marquardt-scaled).
    A column below 1e-10 of the largest in norm (``_RANK_FLOOR`` on J^T J) is
    numerically unidentified, as ``lstsq``'s ``rcond`` would treat it: a colour
    channel of a lobe at ks ~ 1e-20 promises nothing a step can deliver (lifting
    such channels on real materials changed log_rmse by < 0.3%)."""
    lam = jnp.finfo(jtj.dtype).eps ** 0.5
    pinned = pinned_coordinates(jtj, jtr, bound_side)
    delta = _damped_step(jtj, jtr, lam, pinned, floor=_RANK_FLOOR)
    # a held coordinate is at no bound: it has no way to go that a step could take
    gain = 2.0 * jnp.sum(jnp.where(pinned & _in_tail(bound_side), jnp.abs(jtr), 0.0))
    return pinned, jnp.maximum(-(delta @ jtr), 0.0), gain


def decrement(jtj, jtr, bound_side) -> Float[Array, ""]:
    """How much ``sum r^2`` the linear model still promises, pinned coordinates
    included (:func:`split_decrement`)."""
    _, free, gain = split_decrement(jtj, jtr, bound_side)
    return free + gain


def _verdict(loss, free_dec, pinned_gain, gtol, floor) -> Bool[Array, ""]:
    dec = free_dec + pinned_gain
    finite = jnp.isfinite(loss) & jnp.isfinite(dec)
    return finite & ((dec <= gtol * loss) | (loss <= floor))


def is_optimal(loss, jtj, jtr, bound_side, gtol, floor) -> Bool[Array, ""]:
    """The optimality test: a decrement below ``gtol`` of the loss, or a loss below
    ``floor`` (an exact fit, see :func:`exact_fit_floor`)."""
    _, free_dec, gain = split_decrement(jtj, jtr, bound_side)
    return _verdict(loss, free_dec, gain, gtol, floor)


class _LMState(eqx.Module):
    loss: Float[Array, ""]
    jtj: Float[Array, "p p"]
    jtr: Float[Array, " p"]
    lam: Float[Array, ""]
    nu: Float[Array, ""]
    stall: Array  # consecutive accepted steps that changed the loss by < ftol
    stop: Array  # RUNNING, OPTIMAL, STALLED or STUCK
    steps: Array  # steps taken, for the optional traced step limit (``terminate``)
    # split_decrement at the current point, kept for the next step's use
    pinned: Bool[Array, " p"]
    free_dec: Float[Array, ""]
    fresh: Bool[Array, ""]  # the start not yet evaluated: the next step evaluates it
    # sum_i r_i^2 J_i^T J_i at the current point, where the normal equations give it
    # (zeros otherwise): with jtj, the sandwich covariance's terms at the solution
    meat: Float[Array, "p p"]
    result: optx.RESULTS


def _no_bounds(y, args):
    return jnp.zeros(ravel_pytree(y)[0].size, jnp.int32)


class NormalLevenbergMarquardt(optx.AbstractLeastSquaresSolver):
    """Levenberg-Marquardt for small parameter vectors and many residuals.

    ``options`` may hold ``"step_limit"`` (a step limit that may be traced: see
    ``terminate``), ``"normal_equations"`` (see :func:`_residual_and_normal`),
    ``"bound_side"``, ``(y, args) -> (p,) int`` (-1 / +1 where a coordinate sits in
    the flat tail of its transform; see the module docstring), ``"unbounded_above"``,
    ``(y, args) -> (p,) bool`` (the coordinates on a softplus: their step cap is
    relative, :data:`RELATIVE_STEP`) and ``"loss_floor"``, the loss of an exact fit on
    this problem's scale (default ``atol``).
    """

    rtol: float
    atol: float
    norm: Callable = optx.max_norm
    gtol: float = 1e-7
    lambda0: float = 1e-3
    max_step: float = MAX_STEP
    #: A safety net, not the convergence test: ``patience`` accepted steps in a row
    #: that each change the loss by less than ``ftol`` (relative) end the solve as
    #: stalled, unless the optimality test holds.
    ftol: float = 1e-12
    patience: int = 20

    def _bound_side(self, y, args, options):
        return (options or {}).get("bound_side", _no_bounds)(y, args)

    def _step_cap(self, flat, y, args, options):
        """Each coordinate's longest step: ``max_step``, or on a softplus a fraction of
        the coordinate itself where that is more (:data:`RELATIVE_STEP`)."""
        unbounded = (options or {}).get("unbounded_above")
        if unbounded is None:
            return self.max_step
        return jnp.where(unbounded(y, args),
                         jnp.maximum(self.max_step, RELATIVE_STEP * flat), self.max_step)

    def _assess(self, loss, jtj, jtr, y, args, options):
        """(pinned, free decrement, optimal) at a point: one split_decrement serves
        the stop test here and the next step's pinning."""
        floor = (options or {}).get("loss_floor", self.atol)
        pinned, free_dec, gain = split_decrement(jtj, jtr, self._bound_side(y, args, options))
        return pinned, free_dec, _verdict(loss, free_dec, gain, self.gtol, floor)

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        # No evaluation here: the first step evaluates the start (``fresh``). The
        # normal equations are the bulk of a compiled solve, and evaluating them in
        # init too put a second copy of them into every program (~30% of a new
        # process's compile of a GGX solve).
        flat, _ = ravel_pytree(y)
        p, dtype = flat.size, flat.dtype
        return _LMState(
            loss=jnp.asarray(jnp.inf, dtype),
            jtj=jnp.zeros((p, p), dtype),
            jtr=jnp.zeros(p, dtype),
            lam=jnp.asarray(self.lambda0, dtype),
            nu=jnp.asarray(2.0, dtype),
            stall=jnp.asarray(0),
            stop=jnp.asarray(RUNNING),
            steps=jnp.asarray(0),
            pinned=jnp.zeros(p, bool),
            free_dec=jnp.asarray(0.0, dtype),
            fresh=jnp.asarray(True),
            meat=jnp.zeros((p, p), dtype),
            result=optx.RESULTS.successful,
        )

    def step(self, fn, y, args, options, state: _LMState, tags):
        flat, unravel = ravel_pytree(y)
        side = self._bound_side(y, args, options)
        # Pinned coordinates are held while the free ones still move (they may
        # turn back inward as the others settle: a lobe that looked useless at
        # the start), and once those have converged they head for their bound by
        # one full step per iteration (geometrically closer in value). Either
        # way they never shrink the free coordinates' step.
        settled = state.free_dec <= self.gtol * state.loss
        outward = jnp.where(state.pinned & settled & _in_tail(side), self.max_step * side,
                            0.0).astype(flat.dtype)
        delta = _damped_step(state.jtj, state.jtr, state.lam, state.pinned, outward)
        # Cap the step in the unconstrained space: a parameter with a tiny Jacobian
        # column (kd of a dark channel) would otherwise jump deep into the flat tail
        # of its softplus/sigmoid, where its column vanishes and it stays stuck.
        # Each coordinate is capped on its own: scaling the whole step by its
        # longest component let one coordinate sliding down a tail shrink every
        # other one's step to nothing (ggx2 on gold-metallic-paint crawled for 40
        # steps at a constant loss; issue 15).
        cap = self._step_cap(flat, y, args, options)
        delta = jnp.clip(delta, -cap, cap)
        # the first step takes none: it evaluates the start (see init)
        delta = jnp.where(state.fresh, 0.0, delta)
        y_new_flat = flat + delta
        y_new = unravel(y_new_flat)
        loss_new, jtj_new, jtr_new, meat_new = _residual_and_normal(fn, y_new, args, options)

        predicted = -(2.0 * delta @ state.jtr + delta @ state.jtj @ delta)
        actual = state.loss - loss_new
        ok = (
            jnp.isfinite(loss_new) & jnp.all(jnp.isfinite(jtr_new)) & jnp.all(jnp.isfinite(jtj_new))
        )
        rho = jnp.where(predicted > 0, actual / jnp.where(predicted > 0, predicted, 1.0), -1.0)
        accept = ok & ((rho > 1e-4) | state.fresh)

        lam_acc = state.lam * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
        lam = jnp.where(state.fresh, state.lam,
                        jnp.where(accept, lam_acc, state.lam * state.nu))
        nu = jnp.where(state.fresh, state.nu, jnp.where(accept, 2.0, state.nu * 2.0))

        keep = lambda new, old: jnp.where(accept, new, old)  # noqa: E731
        loss, jtj, jtr = (keep(a, b) for a, b in ((loss_new, state.loss), (jtj_new, state.jtj),
                                                   (jtr_new, state.jtr)))
        y_out = keep(y_new_flat, flat)
        meat = state.meat if meat_new is None else keep(meat_new, state.meat)
        pinned, free_dec, optimal = self._assess(loss, jtj, jtr, unravel(y_out), args, options)
        no_progress = jnp.abs(actual) < self.ftol * jnp.abs(state.loss)
        stall = jnp.where(accept & ~state.fresh, jnp.where(no_progress, state.stall + 1, 0),
                          state.stall)
        stalled = jnp.where(stall >= self.patience, STALLED, RUNNING)
        stop = jnp.where(optimal, OPTIMAL, jnp.where(lam > _LAMBDA_MAX, STUCK, stalled))
        state = _LMState(
            loss=loss,
            jtj=jtj,
            jtr=jtr,
            lam=jnp.minimum(lam, 2 * _LAMBDA_MAX),
            nu=nu,
            stall=stall,
            stop=stop,
            steps=state.steps + jnp.where(state.fresh, 0, 1),
            pinned=pinned,
            free_dec=free_dec,
            fresh=jnp.asarray(False),
            meat=meat,
            result=optx.RESULTS.successful,
        )
        return unravel(y_out), state, None

    def terminate(self, fn, y, args, options, state: _LMState, tags):
        # ``options["step_limit"]``, when given, is a step limit that may be traced
        # (``least_squares``' own ``max_steps`` is static: each value would compile
        # its own solve); running out reads as running out of ``max_steps``.
        limit = (options or {}).get("step_limit")
        if limit is None:
            return state.stop != RUNNING, state.result
        out_of_steps = (state.stop == RUNNING) & (state.steps >= limit) & ~state.fresh
        return (state.stop != RUNNING) | out_of_steps, optx.RESULTS.where(
            out_of_steps, optx.RESULTS.nonlinear_max_steps_reached, state.result)

    def postprocess(self, fn, y, aux, args, options, state, tags, result) -> tuple[Any, Any, dict]:
        # num_steps: the steps taken, not counting the evaluation of the start;
        # jtj and meat at y: the sandwich covariance's bread and meat
        return y, aux, {"loss": state.loss, "damping": state.lam, "stop": state.stop,
                        "num_steps": state.steps, "jtj": state.jtj, "meat": state.meat}


def loop_steps(solver, max_steps: int) -> int:
    """The ``max_steps`` to give ``optimistix.least_squares`` for ``max_steps`` steps
    of ``solver``: one more for :class:`NormalLevenbergMarquardt`, whose first
    iteration evaluates the start (its ``num_steps`` does not count that one)."""
    return max_steps + 1 if isinstance(solver, NormalLevenbergMarquardt) else max_steps


def status(result: optx.RESULTS, optimal: Bool[Array, ""]) -> Int[Array, ""]:
    """A finished solve's status (an index into ``STATUS_NAMES``), whatever the
    solver: successful only where the optimality test holds at the returned point."""
    return jnp.where(
        optimal, SUCCESSFUL,
        jnp.where(result == optx.RESULTS.nonlinear_max_steps_reached, MAX_STEPS,
                  jnp.where(result == optx.RESULTS.nonfinite, NONFINITE, STATUS_STALLED)),
    )
